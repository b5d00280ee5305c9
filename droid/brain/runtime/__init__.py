"""droid.brain.runtime -- the Brain's programs and what every program shares (docs/design.md §7, §9).

The programs: ``launcher`` (droid-cell), ``heartbeat`` (droid-heartbeat), ``names``
(droid-names), ``remote`` (droid-remote, with ``sensor_link``, its serial link to a line-laser
sensor), ``keys`` (droid-keys) and ``cheader`` (droid-cheader).  What every DROID program of
every package shares: ``program`` (common options, readiness, presence, stop) and ``rt``
(absolute deadlines, SCHED_FIFO, locked memory).
"""
