"""droid.brain -- the Brain, in four subpackages (docs/design.md §7).

``runtime`` its programs and what every program shares; ``cell`` the cell file, its seam
layout and the device registry; ``db`` the databases and their layouts; ``plumbing`` the
ZeroMQ wire, the links, CURVE and the serial lines.  The modules beside them
(``layouts``, ``classes``, ``registry``) are old paths kept for device packages outside the
repository (``_moved``).
"""
