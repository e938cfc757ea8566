"""Constants of the simulated soft robot: frame timing of the recordings, pressure band, the picture's proportions.

Part of :mod:`lagsplat.synth.continuum_robot` (its docstring describes the model).
"""

from __future__ import annotations

#: Frame interval of the Krauss recordings (s): 119.88 fps video, every 2nd frame.
DT = 1001.0 / 60000.0
#: Frame rate (Hz), exactly ``1 / DT`` (59.94006 fps).
FPS = 60000.0 / 1001.0
#: Band of the random chamber pressures (Hz), as driven by Krauss et al.
PRESSURE_BAND_HZ = (0.04, 2.0)
#: Default clip length (s): 8991 frames, a practical CPU benchmark.
DEFAULT_DURATION_S = 150.0
#: Gravity (m/s^2).
GRAVITY = 9.81

SEGMENTS = (1, 2)

# Picture, in units of the frame height H (horizontal positions relative to W / 2).
MOUNT_Y = 0.08  # robot base below the top edge
REST_FILL = (0.74, 0.64)  # rest length of the whole robot, in H, for 1 and 2 segments (2: room to curl)
HALF_WIDTH = (0.085, 0.062)  # body half-width at the mount and at the tip
MOUNT_HALF_WIDTH = 0.16
RING_LENGTH = 0.05  # connector ring, along the backbone
RING_OVERHANG = 0.012  # ring radius beyond the body
RENDER_NODES = 12  # backbone nodes per segment in the picture
SEG_RGB = ((0.93, 0.92, 0.88), (0.70, 0.80, 0.93))
RING_RGB = (0.12, 0.12, 0.14)
MOUNT_RGB = (0.38, 0.38, 0.41)
BG_GAIN = 0.2  # darkens the shared light background


