"""Fault injection for DROID cells (issue 8; docs/safety.md).

* :mod:`droid.faults.core` — pure, seeded decisions: what happens to each
  message on a faulty link, and which faults a campaign injects;
* :mod:`droid.faults.proxy` — a ZeroMQ man-in-the-middle on one endpoint of
  the cell file (the owner binds the endpoint's ``[interpose]`` inner address);
* :mod:`droid.faults.procs` — kill, pause and resume a cell's programs,
  found through ``droid-cell status``; lock-check every database;
* :mod:`droid.faults.netns` — network namespaces and veth pairs for a
  two-host cell on one machine, and cutting a host off there;
* :mod:`droid.faults.cli` — ``droid-fault``;
* :mod:`droid.faults.campaign` — random faults during motion, with counts of
  runaways, wedged semaphores, leaks and recovery times.
"""
