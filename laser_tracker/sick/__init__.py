"""SICK LMS2xx over a serial line: ``protocol`` (pure telegrams), ``driver`` (pyserial, no
ROS), ``simulator`` (the device on a pseudo-terminal, with fault injection)."""
