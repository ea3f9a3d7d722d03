"""Bundled robot descriptions and recordings (``example_path(name)`` finds them)."""

from pathlib import Path

HERE = Path(__file__).parent

DESCRIPTIONS = {
    "prototype_8mm.toml": "6-cable prototype of Yuan, Courteille & Deblaise 2015, 8 mm steel cables "
                          "(heavy, sagging cables: sag, frf)",
    "prototype_4mm.toml": "the same prototype with 4 mm steel cables",
    "tcpr8.toml": "8-cable redundant robot after Cui et al. 2019 (massless cables: css, workspace, tensions)",
    "csjm.toml": "cable-driven spherical joint module of Yang et al. 2019 (csjm)",
    "csjm_recordings.csv": "rotations and moments recorded on the spherical joint module (csjm --identify)",
    "concealed/robot.toml": "6-cable robot whose recordings conceal an effect (the main job: diagnose)",
    "concealed/recordings.csv": "90 samples of concealed/robot.toml with one effect the description leaves out",
    "example01/robot.toml": "6-cable lab robot, first recorded set",
    "example01/recordings.csv": "90 samples with a temperature covariate (diagnose, fit)",
    "example02/robot.toml": "6-cable lab robot, second recorded set",
    "example02/recordings.csv": "90 clean samples: the description explains them (diagnose gives no effect)",
    "pulleys8/robot.toml": "tcpr8 with 2.5 cm swivel pulleys and stated winch and load-cell gains",
    "suspended3.toml": "3-cable suspended robot (a cable camera): gravity closes the equilibrium "
                       "(forward statics, stiffness of the hanging platform)",
    "suspended4.toml": "4-cable suspended robot after IRMA4U (a 12.99 kg platform under a 4 x 3 x 3 m frame)",
    "pulleys8/recordings.csv": "80 samples of pulleys8/robot.toml (fit the hardware parameters)",
    "onboard4/robot.toml": "4-cable suspended robot with swivel pulleys, calibrated from its own sensors "
                           "(relative winch lengths, load cells, swivel encoders, an AHRS)",
    "onboard4/recordings.csv": "60 samples in 3 sessions without x y z, one concealed effect (diagnose, fit)",
}
"""One line per bundled file: what it is and what it is for (``check --list-examples``)."""


def example_path(name: str) -> Path:
    """Path of a bundled example file, e.g. ``example_path("prototype_8mm.toml")``."""
    p = HERE / name
    if not p.exists():
        avail = sorted(str(q.relative_to(HERE)) for q in HERE.rglob("*") if q.suffix in (".toml", ".csv"))
        raise FileNotFoundError(f"no bundled example {name!r}; available: {', '.join(avail)}")
    return p


def describe_example(name: str) -> str:
    """What the bundled file ``name`` is (:data:`DESCRIPTIONS`)."""
    return DESCRIPTIONS[name]


def list_examples() -> list[str]:
    """Names of the bundled example files."""
    return sorted(str(q.relative_to(HERE)) for q in HERE.rglob("*") if q.suffix in (".toml", ".csv"))
