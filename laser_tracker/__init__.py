"""laser_tracker: detect and track moving objects with a 2D laser scanner on a mobile robot.

Layout: ``core`` is the pure algorithm (numpy/scipy, no ROS), one module per section of the
paper, and its stages (``core.stages``); ``nodes`` thin rclpy shells; ``sick`` the SICK LMS2xx
protocol and driver; ``conversions`` every message conversion; ``config`` and ``parameters``
the declared parameters and their one loader; ``tools`` the offline commands behind
``laser-tracker`` (replay, evaluation, simulator, importers, benchmarks), which need the
``tools`` extra.
"""
__version__ = '0.1.0'
