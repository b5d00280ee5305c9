"""droid.brain.db -- the cell's databases (docs/design.md §3, §7; thesis §3.3).

The fixed record layouts (``layouts``; the C header is generated from them), one record in a
POSIX shared-memory object behind a named semaphore (``shmdb``), which databases a cell has
and their names (``databases``), and the arm commands written into a Command record
(``arm_command``).
"""
