"""quad_il: ROS-free Python side of the imitation-learning pipeline (learning, datasets, tooling).

Submodules never import rospy at module level, so they work in plain Python and in tests without a ROS master.
"""

__version__ = "0.1.0"
