"""droid.brain.cell -- what a cell is (docs/design.md §5, §7, §11).

The cell file (``cellfile``), the seam-tracking layout read beside it (``cell_layout``), the
device registry (``registry``: every package's classes, programs, drivers and twins), the
subunit classes as data (``classes``) and the Brain's own device package (``device``).
"""
