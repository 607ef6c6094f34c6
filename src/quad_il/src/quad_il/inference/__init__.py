"""Inference of the learned policy (issue 8): the Python twin of the C++ package quad_policy.

`config` (config/policy.yaml), `meta` (the exported file's interface parameters), `preprocessing` (the
training preprocessing built from those parameters), `policy` (the TorchScript file), `trajectory` (uniform
cubic B-splines, the stopping trajectory), `safety` (the safety layer), `decider` (one decision), `fixture`
(recorded inputs on disk), `ros_node` (the rospy node), `bench` (the Python side of `make bench-inference`).
docs/inference.md."""
