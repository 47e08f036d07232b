"""laser_tracker: detect and track moving objects with a 2D laser scanner on a mobile robot.

Layout: ``core`` is the pure algorithm (numpy/scipy, no ROS), one module per section of the
paper; ``sim`` the scenario simulator; ``io`` bag and log I/O; ``sick`` the SICK LMS2xx
protocol, driver and device simulator; ``nodes`` thin rclpy shells; ``tools`` the offline
commands behind ``laser-tracker``.
"""
__version__ = '0.1.0'
