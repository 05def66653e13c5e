"""Realism presets of the simulator: which sensor imperfections and world changes a simulated sequence has.

"clean" is the plain simulator (ideal sensor standing still for each scan, static world: the scans of
SIM_VERSION 2, byte for byte). "kitti", the default, is calibrated so that KISS-ICP drift, Scan Context
aliasing and the samplers' spread resemble real KITTI (benchmarks/bench_realism.py measures it):
motion distortion over the 10 Hz sweep, KITTI's HDL-64 elevation error (about -0.22 deg, which kiss-icp's
KITTI loader and msa-slam's KITTI-layout reader correct) with per-beam angle and range errors, range noise
growing with range and incidence, lost dark/grazing returns, mixed pixels at depth edges, foliage, moving and
coming-and-going objects, repeated block designs and stretches with little structure along the road, in a world
that stands along gravity (read from the drive: sim.level), not along the first LiDAR frame's z axis, whose two-way
streets are driven in their right lane (the left side a lane farther out: layout.Style.left_shift). "kitti-hard" is
"kitti" with a less sensitive receiver, larger per-beam errors and more structureless stretches: several times its
odometry drift, for tests.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from msa_slam.errors import InputError
from msa_slam.sim.sensors import SensorRealism
from msa_slam.sim.world import WorldRealism


@dataclass(frozen=True)
class Realism:
    """A preset: the sensor's imperfections (sensors.SensorRealism) and the world's (world.WorldRealism)."""

    sensor: SensorRealism
    world: WorldRealism

    @property
    def is_clean(self) -> bool:
        return self.sensor == SensorRealism.clean() and self.world == WorldRealism.clean()


# min_return_power follows the HDL-64E datasheet: pavement to 50 m, cars and foliage to 120 m. The pavement figure
# is the road as the car-mounted sensor sees it, at grazing incidence, so 10 % pavement 50 m ahead of a sensor
# 1.73 m up is the 50 % point of the return-power model (reflectance x cos(incidence) / range^2 relative to a
# white surface at 10 m: scan.lost_returns), and bright targets then stay within the 120 m range. SIM_VERSION 9
# took that figure at normal incidence (0.005): the road vanished beyond ~20 m, leaving 10-20x fewer returns
# 20-40 m out than KITTI-00's real scans, and without the far road KISS-ICP's pitch drifted ~1 deg per 100 m,
# much of the simulated KITTI-09's vertical drift (docs/simulator.md). At 0.02 far returns flickered from scan to
# scan, which alone took ~0.1 off Scan Context similarity between alike places.
PAVEMENT_RETURN_FLOOR = 0.1 * (1.73 / 50.0) * (10.0 / 50.0) ** 2
KITTI_SENSOR = SensorRealism(
    motion_distortion=True,
    elevation_bias_deg=-0.22,
    elevation_sigma_deg=0.03,
    azimuth_sigma_deg=0.05,
    range_bias_sigma=0.02,
    range_noise_per_m=0.0005,
    incidence_noise=0.002,
    min_return_power=PAVEMENT_RETURN_FLOOR,
    mixed_pixel_prob=0.3,
    mixed_pixel_edge=0.5,
    vegetation_dropout=0.3,
    vegetation_depth=0.2,
)
KITTI_WORLD = WorldRealism(
    moving_cars=2.0,
    pedestrians=2.0,
    transient_parking=0.4,
    parked_occupancy=0.85,
    catalogue_designs=2,
    km_per_design=1.0,
    design_variants=3,
    catalogue_share=0.6,
    hard_share=0.25,
    foliage_gap=0.3,
    upright=True,
    right_hand_traffic=True,
)
# "kitti-hard": odometry that drifts several times as much, for tests of what loop closing must repair. A receiver
# 36x less sensitive (min_return_power 0.005, SIM_VERSION 9's value: the road fades ~20 m out, so KISS-ICP's pitch
# drifts), twice the per-beam calibration errors, and more of the path in stretches where ICP degenerates along
# the street (hard_share 0.45, taken from the repeated designs). docs/simulator.md gives its measured drift.
KITTI_HARD = Realism(
    replace(
        KITTI_SENSOR, min_return_power=0.005, elevation_sigma_deg=0.06, azimuth_sigma_deg=0.1, range_bias_sigma=0.04
    ),
    replace(KITTI_WORLD, hard_share=0.45, catalogue_share=0.4),
)
REALISM: dict[str, Realism] = {
    "clean": Realism(SensorRealism.clean(), WorldRealism.clean()),
    "kitti": Realism(KITTI_SENSOR, KITTI_WORLD),
    "kitti-hard": KITTI_HARD,
}
DEFAULT_REALISM = "kitti"


def get_realism(name: str) -> Realism:
    """The named preset; unknown names raise InputError listing the presets."""
    if name not in REALISM:
        raise InputError(f"unknown realism preset {name!r}; choose one of {', '.join(REALISM)}")
    return REALISM[name]
