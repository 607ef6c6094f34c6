"""Inference of the learned policy (issues 8, 31): the Python node around the C++ core quad_policy, bound as
`core`. Python keeps only the network's preprocessing and forward pass (`policy`); `config` loads
config/policy.yaml with the C++ loader; `fixture` (recorded inputs on disk), `messages` (ROS message
conversion), `ros_node` (the rospy node), `bench` (the Python side of `make bench-inference`),
`random_policy` (test policies). docs/inference.md."""
