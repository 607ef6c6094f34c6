#!/usr/bin/env python3
"""The learned policy in the loop, Python (rospy): quad_il.inference.ros_node. docs/inference.md."""

import sys

from quad_il.inference.ros_node import main

if __name__ == "__main__":
    sys.exit(main())
