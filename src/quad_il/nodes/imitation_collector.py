#!/usr/bin/env python3
"""The interactive imitation-learning collector (rospy): quad_il.imitation.ros_collector.main.
docs/imitation_learning.md ("Pairing and the collector")."""

import sys

from quad_il.imitation.ros_collector import main

if __name__ == "__main__":
    sys.exit(main())
