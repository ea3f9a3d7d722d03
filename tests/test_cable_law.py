"""The one cable-law type (:class:`cstiffjax.cable.laws.CableLaw`) and the statics problem
(:class:`cstiffjax.statics.forward.StaticsProblem`): the names are parsed in one place, every
function that supports only some laws says which, a name passed in Python is refused with
the way to convert it, the law is a reproducible key of the serialized programs, and the
command line reads the names.

References independent of the code under test: the allowed names written out here, the
bilateral spring force written out from Hooke's law, and per-sample solves for the batch."""

import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import cstiffjax
from cstiffjax import CableLaw, StaticsProblem
from cstiffjax.cable import laws
from cstiffjax.csjm import model as csjm
from cstiffjax.dynamics import frf
from cstiffjax.runtime import programs
from cstiffjax.statics import forward as fwd
from cstiffjax.statics import geometry as statics
from cstiffjax.stiffness import matrix

from .helpers import forget_programs, lab_robot

ROBOT, REC = lab_robot("example02")
NAMES = ("spring", "bilateral", "small_sag", "catenary", "ideal")


def test_the_type_is_exported_and_names_every_law_once():
    assert cstiffjax.CableLaw is laws.CableLaw and "CableLaw" in cstiffjax.__all__
    assert cstiffjax.StaticsProblem is fwd.StaticsProblem and "StaticsProblem" in cstiffjax.__all__
    assert tuple(law.name for law in CableLaw) == NAMES
    assert laws.ALL_LAWS == frozenset(CableLaw)


@pytest.mark.parametrize("name", NAMES)
def test_parse_reads_every_name(name):
    law = CableLaw.parse(name)
    assert isinstance(law, CableLaw) and law.name == name and CableLaw.parse(law.name) is law


@pytest.mark.parametrize("text", ["rope", "Spring", "", " catenary", 3, None])
def test_parse_refuses_anything_else_naming_it_and_the_allowed_names(text):
    allowed = ", ".join(repr(n) for n in NAMES)
    with pytest.raises(ValueError) as info:
        CableLaw.parse(text)
    assert str(info.value) == f"unknown cable law {text!r}; allowed: {allowed}"


def test_check_law_refuses_names_and_unsupported_laws():
    assert laws.check_law(CableLaw.small_sag, laws.ALL_LAWS, "f") is CableLaw.small_sag
    with pytest.raises(TypeError, match=r"^f: the law must be a CableLaw member, e.g. CableLaw.spring "
                                        r"\(CableLaw.parse\('catenary'\) reads a name\); got 'catenary'$"):
        laws.check_law("catenary", laws.ALL_LAWS, "f")
    with pytest.raises(TypeError, match=r"got 2$"):
        laws.check_law(2, laws.ALL_LAWS, "f")
    with pytest.raises(ValueError, match=r"^f does not support the 'small_sag' cable law; supported: 'spring', "
                                         r"'bilateral', 'catenary'$"):
        laws.check_law(CableLaw.small_sag, laws.CABLE_FORCE_LAWS, "f")


POSE = REC.pose[0]
L0 = REC.l0[0]
ONE_CABLE = (ROBOT.anchors[0], POSE[:3], 1.0, 1e4, 0.0, jnp.array([0.0, 0.0, -9.81]))


# (call with a law, the name the error gives, the laws it supports)
FUNCTIONS = [
    (lambda law: laws.cable_force(law, *ONE_CABLE), "cable_force", laws.CABLE_FORCE_LAWS),
    (lambda law: statics.elastic_cable_forces(ROBOT, POSE, L0, law), "elastic_cable_forces", laws.CABLE_FORCE_LAWS),
    (lambda law: statics.elastic_wrench(ROBOT, POSE, L0, None, law), "elastic_wrench", laws.CABLE_FORCE_LAWS),
    (lambda law: matrix.stiffness_from_lengths(ROBOT, POSE, L0, law), "stiffness_from_lengths",
     laws.CABLE_FORCE_LAWS),
    (lambda law: matrix.to_euler_coordinates(ROBOT, POSE, L0, None, law), "to_euler_coordinates",
     laws.CABLE_FORCE_LAWS),
    (lambda law: frf.cable_statics_from_lengths(ROBOT, POSE, L0, law), "cable_statics_from_lengths",
     laws.CABLE_FORCE_LAWS),
    (lambda law: fwd.solve_unknowns(StaticsProblem(ROBOT, L0, law=law), pose0=POSE), "solve_unknowns",
     laws.ALL_LAWS - {CableLaw.ideal}),
]


@pytest.mark.parametrize("call, name, supported", FUNCTIONS, ids=[f[1] for f in FUNCTIONS])
def test_each_function_says_which_laws_it_supports(call, name, supported):
    """Every law outside the function's set is a ``ValueError`` naming the function, the law
    and the set; a name instead of a member is a ``TypeError`` (refused before any solve)."""
    listed = ", ".join(repr(n) for n in NAMES if CableLaw[n] in supported)
    for law in frozenset(CableLaw) - supported:
        with pytest.raises(ValueError, match=f"{name} does not support the '{law.name}' cable law; "
                                             f"supported: {listed}(?!,)"):
            call(law)
    with pytest.raises(TypeError, match="CableLaw.parse"):
        call("spring")


def test_the_fits_and_the_model_say_which_laws_they_support():
    from fitting.calibration.least_squares import calibrate
    from fitting.calibration.models import FIT_LAWS, predict_cdpr
    from fitting.diagnosis.diagnose import diagnose
    from fitting.effects import build_data, make_model

    assert FIT_LAWS == {CableLaw.spring, CableLaw.catenary}
    rec = REC.select(np.arange(3))
    calls = {"calibrate": lambda law: calibrate(ROBOT, rec, law=law),
             "diagnose": lambda law: diagnose(ROBOT, rec, law=law),
             "predict_cdpr": lambda law: predict_cdpr(ROBOT, rec.l0, rec.wrench, law=law)}
    for law in (CableLaw.bilateral, CableLaw.small_sag, CableLaw.ideal):
        for name, call in calls.items():
            with pytest.raises(ValueError, match=f"{name}.* does not support the '{law.name}' cable law; "
                                                 f"supported: 'spring', 'catenary'(?!,)"):
                call(law)
    with pytest.raises(ValueError, match="make_model does not support the 'ideal' cable law"):
        make_model(ROBOT, build_data(rec), [], CableLaw.ideal)
    with pytest.raises(TypeError, match="CableLaw.parse"):
        make_model(ROBOT, build_data(rec), [], "spring")


def test_the_per_cable_forces_take_the_bilateral_law():
    """``elastic_cable_forces`` takes every law that has a one-cable force, ``bilateral``
    included: Hooke's law on the unstrained length, written out here, pushing when the
    cable is shorter than ``l0`` (where the one-sided spring carries nothing)."""
    R = np.asarray(cstiffjax.lie.exp(POSE[3:]))
    d = np.asarray(ROBOT.anchors) - (np.asarray(POSE[:3]) + np.asarray(ROBOT.attachments) @ R.T)
    length = np.linalg.norm(d, axis=1)
    l0 = length * np.array([0.99, 1.01, 0.995, 1.02, 0.98, 1.0])
    t = np.asarray(ROBOT.EA) * (length - l0) / l0
    bil = statics.elastic_cable_forces(ROBOT, POSE, jnp.asarray(l0), CableLaw.bilateral)
    spr = statics.elastic_cable_forces(ROBOT, POSE, jnp.asarray(l0), CableLaw.spring)
    np.testing.assert_allclose(bil.on_platform, t[:, None] * d / length[:, None], rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(spr.on_platform, np.maximum(t, 0)[:, None] * d / length[:, None], rtol=1e-12,
                               atol=1e-9)
    assert np.any(t < 0) and np.any(t > 0)  # both sides of the kink are exercised


def test_csjm_moment_takes_the_type():
    rb = cstiffjax.load_robot(cstiffjax.example_path("csjm.toml"))
    l0 = jnp.full(rb.num_cables, 0.1)
    with pytest.raises(ValueError, match="elastic_moment does not support the 'small_sag' cable law"):
        csjm.elastic_moment(rb, jnp.zeros(3), l0, CableLaw.small_sag)
    with pytest.raises(TypeError, match="CableLaw.parse"):
        csjm.elastic_moment(rb, jnp.zeros(3), l0, "spring")


def test_a_statics_problem_checks_its_shapes_and_a_batch_of_them_vmaps():
    """A problem with leading batch axes is what ``jax.vmap(forward_statics)`` maps over: the
    same equilibria as one problem per sample."""
    with pytest.raises(ValueError, match=r"l0 has shape \(2, 5\); robot 'example02' has 6 cables"):
        StaticsProblem(ROBOT, REC.l0[:2, :5])
    with pytest.raises(ValueError, match=r"external has shape \(6, 3\)"):
        StaticsProblem(ROBOT, REC.l0[0], jnp.zeros((6, 3)))
    n = 3
    batch = StaticsProblem(ROBOT, REC.l0[:n], REC.wrench[:n], CableLaw.bilateral)
    assert batch.l0.dtype == jnp.float64 and batch.law is CableLaw.bilateral

    @jax.jit
    def solve(problem, pose0):
        return fwd.forward_statics(problem, pose0=pose0, start="warm")

    axes = eqx.tree_at(lambda p: (p.l0, p.external), jax.tree.map(lambda _: None, batch), (0, 0),
                       is_leaf=lambda x: x is None)  # the robot is shared
    together = jax.vmap(solve, in_axes=(axes, 0))(batch, REC.pose[:n])
    for i in range(n):
        one = solve(StaticsProblem(ROBOT, REC.l0[i], REC.wrench[i], CableLaw.bilateral), REC.pose[i])
        np.testing.assert_allclose(together.pose[i], one.pose, rtol=0, atol=1e-12)
        np.testing.assert_allclose(together.tensions[i], one.tensions, rtol=1e-12)
    assert bool(jnp.all(together.result == cstiffjax.Status.successful))


# ------------------------------------------------------------------ the law as a program key
TRACES = []


def _scaled(x, law):
    TRACES.append(law)  # runs only while JAX traces
    return x * (2.0 if law is CableLaw.catenary else 3.0)


def test_a_law_is_a_reproducible_key_of_the_serialized_programs(tmp_path, monkeypatch):
    """The law's text in the key names the type and the member (no address): a second
    process loads the serialized program, and each law has its own."""
    monkeypatch.setattr(programs, "_COVERED", programs._COVERED | {"tests"})
    text = programs._static_text(CableLaw.catenary)
    assert " at 0x" not in text and "CableLaw" in text and "catenary" in text
    assert text != programs._static_text(CableLaw.spring)
    programs.set_folder(tmp_path)
    try:
        x = jnp.arange(3.0, dtype=jnp.float64)
        for law, factor in ((CableLaw.catenary, 2.0), (CableLaw.spring, 3.0)):
            forget_programs()
            out = programs.Program(_scaled, name="tests.law", like=lambda args: 0)(x, law)
            np.testing.assert_array_equal(out, factor * np.arange(3.0))
        assert TRACES == [CableLaw.catenary, CableLaw.spring] and len(list(tmp_path.glob("*.jaxexport"))) == 2
        forget_programs()  # a new process's view
        prog = programs.Program(_scaled, name="tests.law", like=lambda args: 0)
        np.testing.assert_array_equal(prog(x, CableLaw.catenary), 2.0 * np.arange(3.0))
        assert len(TRACES) == 2 and len(list(tmp_path.glob("*.jaxexport"))) == 2  # loaded, not traced
    finally:
        programs.set_folder(None)
        forget_programs()


# ------------------------------------------------------------------------- the command line
def test_the_command_line_reads_the_names(capsys):
    from cstiffjax.commands.cli import main

    with pytest.raises(SystemExit) as info:
        main(["fit", "example02/robot.toml", "example02/recordings.csv", "--law", "rope"])
    assert info.value.code == 1
    choices = r"\(choose from '?spring'?, '?catenary'?\)"  # (quoted from Python 3.12.8 on)
    assert re.search(f"argument --law: invalid choice: 'rope' {choices}", capsys.readouterr().err)
    with pytest.raises(SystemExit):
        main(["diagnose", "--law", "small_sag"])
    assert re.search(f"argument --law: invalid choice: 'small_sag' {choices}", capsys.readouterr().err)


def test_the_diagnosis_json_holds_the_names():
    from fitting.diagnosis.report import validate_diagnosis
    from fitting.diagnosis.selection import Candidate

    c = Candidate("cable_mass", -20.0, 1.0, {}, 1, 0.0, 0.0, True, 0.5, law=CableLaw.small_sag)
    assert c.to_json()["law"] == "small_sag"
    with pytest.raises(ValueError, match=r"'baseline.model': value 'bilateral'; allowed: 'spring', 'catenary'$"):
        validate_diagnosis({"robot": "r", "samples": 1, "baseline": {"model": "bilateral"}, "localization": [],
                            "candidates": [], "effects": [], "explained": True, "final": {}})


def test_a_problem_is_a_module_whose_law_is_static():
    p = StaticsProblem(ROBOT, L0, law=CableLaw.catenary)
    leaves, treedef = jax.tree_util.tree_flatten(p)
    assert all(isinstance(x, jax.Array) for x in leaves)  # the law is not a leaf
    assert "CableLaw.catenary" in str(treedef) and " at 0x" not in str(treedef)
    assert treedef == jax.tree_util.tree_structure(StaticsProblem(ROBOT, 2 * L0, law=CableLaw.catenary))
    assert treedef != jax.tree_util.tree_structure(StaticsProblem(ROBOT, L0, law=CableLaw.spring))
    assert jax.tree_util.tree_unflatten(treedef, leaves).law is CableLaw.catenary
