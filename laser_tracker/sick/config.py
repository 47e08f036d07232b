"""The SICK LMS2xx driver node's parameters (no pyserial here: the parameter registry and
the offline tools import this without a serial library).

The node is a lifecycle node. The connection parameters (:data:`CONFIGURE_FIELDS`) are read
when it is configured (port opened, device set up); a change while it is configured is
accepted and applies at the next configure. The others apply at once.
"""
from __future__ import annotations

from dataclasses import dataclass

from laser_tracker.config import ConfigError, param
from laser_tracker.sick import protocol as P

#: Read when the node is configured (the port is opened and the device set up with them).
CONFIGURE_FIELDS = ('port', 'baud', 'scan_angle', 'resolution', 'units', 'password')
AT_CONFIGURE = ' Applied at configure: after a change, cleanup and configure the node again.'


@dataclass(frozen=True)
class SickLmsConfig:
    """The driver node's parameters (plain names: ``port``, ``baud``, ...)."""

    autostart: bool = param(True, 'Configure and activate at start-up, retrying every '
                            'reconnect_period until the device answers (ros2 run); false: '
                            'wait for a lifecycle manager (ros2 lifecycle set ... configure).',
                            read_only='it is read at start-up')
    port: str = param('/dev/ttyUSB0', 'Serial port of the LMS2xx (a device or a symlink).'
                      + AT_CONFIGURE)
    baud: int = param(38400, 'Line rate to run at; the driver finds the rate the device is at '
                      'and switches it. 500000 needs an RS-422 adapter.' + AT_CONFIGURE,
                      choices=(9600, 19200, 38400, 500000))
    scan_angle: int = param(180, 'Scan angle in degrees (180: -90..+90, 100: -50..+50).'
                            + AT_CONFIGURE, choices=(100, 180))
    resolution: float = param(0.5, 'Angular resolution in degrees; 0.5 and 0.25 are interlaced '
                              'by the device over 2 and 4 mirror turns; 0.25 needs the 100 '
                              'degree scan angle.' + AT_CONFIGURE, choices=(1.0, 0.5, 0.25))
    units: str = param('mm', 'Range units: mm (8.18 m range) or cm (81.8 m range).'
                       + AT_CONFIGURE, choices=('mm', 'cm'))
    password: str = param(P.DEFAULT_PASSWORD, 'Installation-mode password (8 characters), '
                          'needed to change the units.' + AT_CONFIGURE)
    frame_id: str = param('laser', 'Frame of the published scans.')
    inverted: bool = param(False, 'Scanner mounted upside down: beams are reversed so angles '
                           'stay counter-clockwise about an upward z axis.')
    time_offset: float = param(0.0, 'Seconds added to every stamp: calibrates the device '
                               'latency the stamp model cannot know (stamps stay strictly '
                               'increasing when it is lowered while streaming).',
                               min=-1.0, max=1.0)
    reply_timeout: float = param(0.5, 'Seconds to wait for the answer to a command (plus the '
                                 'transmission time at the line rate).', min=0.05, max=30.0)
    silence_timeout: float = param(1.0, 'Seconds without a good scan (plus 3 telegram times) '
                                   'after which the device is re-initialised.',
                                   min=0.1, max=60.0)
    reconnect_period: float = param(1.0, 'Seconds between attempts to open and initialise a '
                                    'lost or absent device.', min=0.05, max=60.0)
    diagnostics_period: float = param(1.0, 'Seconds (wall time, also with use_sim_time) '
                                      'between /diagnostics messages.', min=0.1, max=60.0)

    def __post_init__(self):
        try:
            P.check_variant(self.scan_angle, self.resolution_cdeg)
        except ValueError as exc:
            raise ConfigError(f'scan_angle/resolution: {exc}') from None
        if len(self.password) != 8 or not self.password.isascii():
            raise ConfigError('password: must be 8 ASCII characters')

    @property
    def resolution_cdeg(self) -> int:
        return int(round(self.resolution * 100))

    @property
    def variant(self) -> P.VariantSpec:
        return P.VariantSpec(self.scan_angle, self.resolution_cdeg)

    @property
    def range_unit(self) -> P.RangeUnit:
        return P.RangeUnit.parse(self.units)
