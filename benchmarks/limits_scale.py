"""Data of the ``scale`` group of ``benchmarks/bench_limits.py``: thousands of distinct on-board
samples of the bundled ``onboard4`` robot, and large CASPR cables files.

- :func:`onboard_samples`: ``n`` distinct samples of ``onboard4`` as
  ``benchmarks/make_onboard_example.py`` makes its 60 (positions uniform in the same box, three
  sessions with their own length and yaw zeros, load cells 4 % high on cable 1 and 3 % low on
  cable 3): a diagnosis must name ``tension_sensor_gain``.
- :func:`caspr_files`: a bodies file (CoGiRo's platform) and a cables file of ``n`` straight
  ``cable_ideal`` cables in one cable set, about 390 bytes per cable, as CASPR writes them.
"""

import math
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ONBOARD = ROOT / "cstiffjax" / "examples" / "onboard4"
GAIN = (1.04, 1.0, 0.97, 1.0)


def onboard_samples(n: int, folder, seed: int = 7) -> None:
    """Write ``folder/robot.toml`` (onboard4's nominal description) and ``folder/recordings.csv``
    (``n`` samples in 3 sessions, each session's clock from 0 s every 15 s). Samples whose
    nominal equilibrium the cold-start statics does not find (the fit and the diagnosis start
    there; 2 of 6 000 at seed 7) are drawn again, so every recorded sample can be fitted."""
    import dataclasses

    import equinox as eqx
    import numpy as np

    import cstiffjax  # noqa: F401  (float64)
    from cstiffjax.core.arrays import to_device
    from cstiffjax.core.status import to_codes
    from cstiffjax.io import schema
    from cstiffjax.io.recordings import write_recordings
    from cstiffjax.io.robot_io import load_robot, save_robot
    from fitting.calibration.models import _cold_starts
    from fitting.synth.onboard import hanging_lengths, onboard_recordings

    robot = load_robot(ONBOARD / "robot.toml")
    truth = eqx.tree_at(lambda r: r.tension_gain, robot, np.array(GAIN))
    rng = np.random.default_rng(seed)
    session = np.repeat([0, 1, 2], -(-n // 3))[:n]
    zeros, yaw = rng.normal(0.0, 0.003, (3, 4)), np.array([0.05, -0.4, 1.2])
    positions = rng.uniform([-0.8, -0.6, 1.0], [0.8, 0.6, 2.0], (n, 3))
    for _ in range(5):
        rec = onboard_recordings(truth, hanging_lengths(truth, positions), session=session, length_zero=zeros,
                                 yaw_zero=yaw, seed=seed)
        _, res = _cold_starts(dataclasses.replace(robot, name="robot"), to_device(rec.l0, np.float64),
                              to_device(rec.wrench, np.float64))  # as fitting.calibration.models.start_poses
        bad = np.flatnonzero(np.asarray(to_codes(res)) != 0)
        if not bad.size:
            break
        positions[bad] = rng.uniform([-0.8, -0.6, 1.0], [0.8, 0.6, 2.0], (bad.size, 3))
    else:
        raise RuntimeError(f"no nominal equilibrium for samples {bad.tolist()} after 5 draws")
    time = np.concatenate([np.arange(np.sum(session == s)) * 15.0 for s in range(3)])
    cols = schema.to_columns(4, {"session": rec.session, "time": time, "l0": rec.l0, "tensions": rec.tensions,
                                 "swivel": rec.swivel, "ahrs": rec.ahrs})
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    save_robot(robot, folder / "robot.toml")
    write_recordings(cols, folder / "recordings.csv")


_BODY = """<?xml version="1.0" encoding="utf-8"?>
<bodies_system>
  <links>
    <link_rigid num="1" name="big">
      <joint type="SPATIAL_EULER_XYZ" q_initial="0 0 2.0 0 0 0"/>
      <physical>
        <mass>91.058</mass>
        <com_location>-0.034 -0.013 0.264</com_location>
        <inertia ref="com">
          <Ixx>36.598</Ixx><Iyy>35.982</Iyy><Izz>25.439</Izz><Ixy>-0.453</Ixy><Ixz>3.012</Ixz><Iyz>-1.539</Iyz>
        </inertia>
      </physical>
      <parent><num>0</num><location>0.0 0.0 0.0</location></parent>
    </link_rigid>
  </links>
</bodies_system>
"""


def caspr_files(n: int, folder) -> tuple[Path, Path]:
    """Write ``folder/big_bodies.xml`` and ``folder/big_cables.xml`` (``n`` cables around an
    ellipse 14 m x 10 m at 5.4 m, attachments on a 1 m platform) and return their paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    bodies, cables = folder / "big_bodies.xml", folder / "big_cables.xml"
    bodies.write_text(_BODY)
    with cables.open("w") as f:
        f.write('<?xml version="1.0" encoding="utf-8"?>\n<cables default_cable_set="big">\n  <cable_set id="big">\n')
        for i in range(n):
            th = 2 * math.pi * i / n
            f.write(f'    <cable_ideal name="cable {i + 1}" attachment_reference="joint">\n'
                    f"      <properties><force_min>100.0</force_min><force_max>5000</force_max></properties>\n"
                    f"      <attachments>\n"
                    f"        <attachment><link>0</link><location>{7 * math.cos(th):.6f} {5 * math.sin(th):.6f} "
                    f"5.4</location></attachment>\n"
                    f"        <attachment><link>1</link><location>{0.5 * math.cos(th + 1):.6f} "
                    f"{0.4 * math.sin(th + 1):.6f} {i % 2}</location></attachment>\n"
                    f"      </attachments>\n    </cable_ideal>\n")
        f.write("  </cable_set>\n</cables>\n")
    return bodies, cables
