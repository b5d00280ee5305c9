"""droid-ros2: the cell as a ROS 2 node (issue 42; docs/ros2.md; docs/design.md §12).

* :mod:`droid.ros2.env` -- the environment the PyPI ROS 2 wheels need (library path, middleware,
  loopback discovery, domain id), set by the program itself;
* :mod:`droid.ros2.trajectory` -- a trajectory_msgs/JointTrajectory checked and turned into droid-move's
  joint moves (pure: no ROS import);
* :mod:`droid.ros2.node` -- the program: publishers on the Brain's Status, and with
  ``--allow-commands`` the trajectory topic and the home/stop services.
"""
