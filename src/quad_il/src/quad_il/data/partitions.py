"""What a demonstration record means to the trainer: the partition codes of the `il_partition` npz column.

The interactive learners (quad_il.imitation) label each record with a partition; the converter writes the
codes into the training npz and the trainer (quad_il.learning.dataset, the EIL loss) reads them. The
vocabulary lives here, below both, so neither imports the other for it (issue 31: no import cycle between
subpackages).
"""

from __future__ import annotations

import enum


class Partition(enum.Enum):
    """What a record means to the trainer (EIL's partitions; BC/DAgger/HG-DAgger use DEMO or INTERVENTION)."""

    DEMO = "demo"  # expert label on a state (BC, DAgger): plain regression target
    INTERVENTION = "intervention"  # expert in control, expert label (HG-DAgger, EIL, MEGA-DAgger)
    GOOD = "good"  # learner in control, no intervention followed: the learner's action was good enough (EIL)
    BAD = "bad"  # learner in control just before an intervention: the learner's action was bad (EIL)


PARTITION_CODES: dict[Partition, int] = {
    Partition.DEMO: 0,
    Partition.INTERVENTION: 1,
    Partition.GOOD: 2,
    Partition.BAD: 3,
}
# The npz array (quad_il.imitation.convert) holding each row's PARTITION_CODES value; rows of files without it
# (the C++ collector's) are DEMO.
IL_PARTITION_KEY = "il_partition"
