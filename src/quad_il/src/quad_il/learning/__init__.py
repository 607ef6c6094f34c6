"""ROS-free learning stack of quad_il (issue 7): policy network, losses, schedulers, datasets, training,
metrics.

Modules: `mobilenet_v3` (backbone with torchvision's names), `preprocessing` (depth/state/output transforms
shared with the exported policy), `model` (thesis network + `Policy`), `losses`, `schedulers`, `metrics`,
`dataset`, `config`, `trainer`, `export`, `evaluation`, `plots`, `synthetic`, `bench`. See docs/learning.md.
"""
