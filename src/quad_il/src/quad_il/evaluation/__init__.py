"""Closed-loop evaluation (issue 8, `make eval`): the same held-out seeded worlds and start/goal pairs flown
by the expert, the Python policy and the C++ policy, through the simulator's reset service.

`episodes` (the episode list and results, ROS-free), `metrics` (clearance geometry and per-controller
summaries, ROS-free), `runner` (the rospy episode runner), `run_eval` (the orchestrator: one simulator +
tracker + controller launch per controller), `report` (Markdown report, plots, BENCH lines).
docs/inference.md, "Closed-loop evaluation"."""
