"""Record, replay and watch a cell (thesis §3.4 "to a Graphical User Interface or through a
TCP/IP network port to be visualized on a remote station or a web page"; §7.3).

Observers read the Brain's databases only, like a task (docs/design.md §7: they import
``brain`` and ``kinematics``, never ``sim``), and never write a Command:

* :mod:`droid.observe.mcapfile` -- the MCAP layout of a DROID recording (writer + checked reader);
* :mod:`droid.observe.schemas`  -- JSON Schemas of the records, derived from the layouts' dtypes;
* :mod:`droid.observe.scene`    -- frames and geometry (FrameTransforms, SceneUpdate, link frames);
* :mod:`droid.observe.sampler`  -- one snapshot of a running cell's databases per heartbeat tick;
* :mod:`droid.observe.record`   -- ``droid-record`` (and the hooks of droid-seamtrack / droid-experiment);
* :mod:`droid.observe.replay`   -- ``droid-replay`` (into a ``droid-cell up --replay`` cell; CSV export);
* :mod:`droid.observe.web`      -- ``droid-web`` (live page, 3-D view, recordings with a time slider);
  :mod:`droid.observe.sources` and :mod:`droid.observe.view` -- its snapshots, live or from a file;
* :mod:`droid.observe.foxglove` -- ``droid-foxglove`` (the cell on a Foxglove WebSocket; extra ``droid[foxglove]``);
* :mod:`droid.observe.events`   -- faults and events between snapshots (foxglove ``Log``);
* :mod:`droid.observe.lockstep` -- lockstep trials into the same layout.

``droid-replay`` is the one program here that writes databases: the Status and
Command records of a *replay* cell, which has no programs of its own.
See docs/observe.md.
"""
