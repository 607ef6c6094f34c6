"""Episode management for demonstration collection (ROS-free; the rospy node is nodes/episode_manager.py)."""
