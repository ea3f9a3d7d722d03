"""CASPR models read as robot descriptions (cstiffjax.io.caspr, ``cstiffjax convert``).

The models below are CASPR's own, re-typed by hand from the CASPR repository
(github.com/darwinlau/CASPR, ``data/model_config/models/``) in CASPR's element/attribute
structure, and the expected arrays are typed a second time from the same files:

- CoGiRo (``SCDM/spatial_manipulators/CoGiRo/CoGiRo_bodies.xml``, ``CoGiRo_cables.xml``,
  cable set ``original``): 91.058 kg, com (-0.034, -0.013, 0.264), a full inertia with
  products, 8 suspended cable_ideal cables with ``attachment_reference="joint"``, limits
  100..5000 N, ``q_initial = 0 0 2 0 0 0``.
- Example spatial (``examples/Example_spatial/``, cable sets ``basic_7_cables`` (the file's
  ``default_cable_set``) and ``basic_8_cables``): 1 kg, com at the origin,
  ``attachment_reference="com"``, ``q_initial = 0.5 0.5 0.5 0 0 0``.
- IPAnema 2's body (``SCDM/spatial_manipulators/IPAnema_2/IPAnema_2_bodies.xml``: 10 kg, com
  (0, 0, 0.5), inertia 1, 1, 1 about the com) written with ``ref="joint"``: 3.5, 3.5, 1 about
  the joint origin (parallel axes, by hand: 1 + 10 * 0.5^2).
- Example planar XY and a two-link body after Example 2R planar XZ, for the refusals.
"""

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cstiffjax.commands.cli import main
from cstiffjax.core.lie import exp as so3_exp
from cstiffjax.io.caspr import CasprModelError, pose_from_q, read_caspr
from cstiffjax.io.robot_io import load_description, robot_to_toml
from cstiffjax.statics.geometry import structure_matrix

BODY = """<?xml version="1.0" encoding="utf-8"?>
<!DOCTYPE bodies_system SYSTEM "../../../../templates/bodies.dtd">
<bodies_system>
  <links display_range="-8 8 -6 6 0 6" view_angle="-37 32">
    <link_rigid num="1" name="{name}">
      <joint type="{joint}" q_initial="{q}" q_min="-7.0 -5.0 0.0 -3.1416 -3.1416 -3.1416"
             q_max="7.0 5.0 5.0 3.1416 3.1416 3.1416"/>
      <physical>
        <mass>{mass}</mass>
        <com_location>{com}</com_location>
        <end_location>0.0 0.0 0.0</end_location>
        <inertia ref="{ref}">
          <Ixx>{I[0]}</Ixx><Iyy>{I[1]}</Iyy><Izz>{I[2]}</Izz><Ixy>{I[3]}</Ixy><Ixz>{I[4]}</Ixz><Iyz>{I[5]}</Iyz>
        </inertia>
      </physical>
      <parent><num>0</num><location>0.0 0.0 0.0</location></parent>
    </link_rigid>
  </links>
</bodies_system>
"""


def body(name="CoGiRo", joint="SPATIAL_EULER_XYZ", q="0 0 2.0 0 0 0", mass="91.058", com="-0.034 -0.013 0.264",
         ref="com", inertia=("36.598", "35.982", "25.439", "-0.453", "3.012", "-1.539")):
    return BODY.format(name=name, joint=joint, q=q, mass=mass, com=com, ref=ref, I=inertia)


def cable(name, base, platform, kind="cable_ideal", ref="joint", fmin="100.0", fmax="5000", extra=""):
    return (f'    <{kind} name="{name}" attachment_reference="{ref}">\n'
            f"      <properties>{extra}<force_min>{fmin}</force_min><force_max>{fmax}</force_max></properties>\n"
            f"      <attachments>\n"
            f"        <attachment><link>0</link><location>{base}</location></attachment>\n"
            f"        <attachment><link>1</link><location>{platform}</location></attachment>\n"
            f"      </attachments>\n    </{kind}>\n")


COGIRO_CABLES = [  # CoGiRo_cables.xml, cable set "original": (link 0 location, link 1 location)
    ("-7.1775 -5.4361 5.3911", "0.5032 -0.4928 0.0"),
    ("-7.4594 -5.1504 5.3999", "-0.5097 0.3508 0.9976"),
    ("-7.3911 5.1940 5.3976", "-0.5032 -0.2700 0.0"),
    ("-7.1026 5.4753 5.4094", "0.4960 0.3561 0.9996"),
    ("7.2398 5.3759 5.4093", "-0.5032 0.4928 0.0"),
    ("7.5208 5.0851 5.4200", "0.4998 -0.3404 0.9991"),
    ("7.4461 -5.2539 5.3874", "0.5021 0.2750 -0.0007"),
    ("7.1608 -5.5342 5.3973", "-0.5045 -0.3463 0.9976"),
]
COGIRO_ANCHORS = np.array([
    [-7.1775, -5.4361, 5.3911], [-7.4594, -5.1504, 5.3999], [-7.3911, 5.1940, 5.3976], [-7.1026, 5.4753, 5.4094],
    [7.2398, 5.3759, 5.4093], [7.5208, 5.0851, 5.4200], [7.4461, -5.2539, 5.3874], [7.1608, -5.5342, 5.3973]])
COGIRO_ATTACHMENTS = np.array([
    [0.5032, -0.4928, 0.0], [-0.5097, 0.3508, 0.9976], [-0.5032, -0.2700, 0.0], [0.4960, 0.3561, 0.9996],
    [-0.5032, 0.4928, 0.0], [0.4998, -0.3404, 0.9991], [0.5021, 0.2750, -0.0007], [-0.5045, -0.3463, 0.9976]])


def cables_file(sets, default=None):
    head = f' default_cable_set="{default}"' if default else ""
    body_ = "".join(f'  <cable_set id="{sid}">\n{"".join(cs)}  </cable_set>\n' for sid, cs in sets)
    return f'<?xml version="1.0" encoding="utf-8"?>\n<cables{head}>\n{body_}</cables>\n'


def cogiro_cables(**kw):
    return cables_file([("original", [cable(f"cable {i}", b, p, **kw) for i, (b, p) in
                                      enumerate(COGIRO_CABLES, 1)])], default="original")


# Example_spatial_cables.xml: basic_7_cables then basic_8_cables (5 N .. 300 N, reference "com")
SPATIAL_7 = [("0.0 0.0 1.0", "-0.15 -0.1 0.05"), ("1.0 0.0 1.0", "0.15 -0.1 0.05"), ("1.0 1.0 1.0", "0.15 0.1 0.05"),
             ("0.0 1.0 1.0", "-0.15 0.1 0.05"), ("0.5 0.0 0.0", "0.0 -0.1 -0.05"), ("1.0 1.0 0.0", "0.15 0.1 -0.05"),
             ("0.0 1.0 0.0", "-0.15 0.1 -0.05")]
SPATIAL_8 = [("0.0 0.0 1.0", "-0.15 -0.1 0.05"), ("1.0 0.0 1.0", "0.15 -0.1 0.05"), ("1.0 1.0 1.0", "0.15 0.1 0.05"),
             ("0.0 1.0 1.0", "-0.15 0.1 0.05"), ("1.0 1.0 0.0", "0.15 0.1 -0.05"), ("0.0 1.0 0.0", "-0.15 0.1 -0.05"),
             ("0.0 0.0 0.0", "-0.15 -0.1 -0.05"), ("1.0 0.0 0.0", "0.15 -0.1 -0.05")]
SPATIAL_8_ANCHORS = np.array([[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1], [1, 1, 0], [0, 1, 0], [0, 0, 0], [1, 0, 0]],
                             dtype=float)
SPATIAL_8_ATTACHMENTS = np.array([[-0.15, -0.1, 0.05], [0.15, -0.1, 0.05], [0.15, 0.1, 0.05], [-0.15, 0.1, 0.05],
                                  [0.15, 0.1, -0.05], [-0.15, 0.1, -0.05], [-0.15, -0.1, -0.05], [0.15, -0.1, -0.05]])


def spatial_files(tmp_path):
    b = tmp_path / "Example_spatial_bodies.xml"
    b.write_text(body(name="Spatial Manipulator", q="0.5 0.5 0.5 0 0 0", mass="1", com="0.0 0.0 0.0",
                      inertia=("0.0042", "0.0083", "0.0108", "0.0", "0.0", "0.0")))
    c = tmp_path / "Example_spatial_cables.xml"
    sets = [(sid, [cable(f"cable {i}", bb, p, ref="com", fmin="5.0", fmax="300") for i, (bb, p) in enumerate(cs, 1)])
            for sid, cs in (("basic_7_cables", SPATIAL_7), ("basic_8_cables", SPATIAL_8))]
    c.write_text(cables_file(sets, default="basic_7_cables"))
    return b, c


def write(tmp_path, bodies_text, cables_text, stem="CoGiRo"):
    b, c = tmp_path / f"{stem}_bodies.xml", tmp_path / f"{stem}_cables.xml"
    b.write_text(bodies_text)
    c.write_text(cables_text)
    return b, c


def rank(robot, pose):
    return int(np.linalg.matrix_rank(np.asarray(structure_matrix(robot, np.asarray(pose)))))


def test_cogiro_numbers_and_rank(tmp_path):
    model = read_caspr(*write(tmp_path, body(), cogiro_cables()), ea=2e5)
    r = model.robot
    np.testing.assert_array_equal(np.asarray(r.anchors), COGIRO_ANCHORS)
    np.testing.assert_array_equal(np.asarray(r.attachments), COGIRO_ATTACHMENTS)  # reference "joint": as written
    assert float(r.platform_mass) == 91.058 and r.name == "CoGiRo"
    np.testing.assert_array_equal(np.asarray(r.com), [-0.034, -0.013, 0.264])
    np.testing.assert_array_equal(np.asarray(r.inertia), [[36.598, -0.453, 3.012], [-0.453, 35.982, -1.539],
                                                          [3.012, -1.539, 25.439]])
    assert (float(r.tension_min), float(r.tension_max)) == (100.0, 5000.0)
    np.testing.assert_array_equal(np.asarray(r.EA), np.full(8, 2e5))
    np.testing.assert_array_equal(np.asarray(r.gravity), [0, 0, -9.81])
    assert model.cable_set == "original" and model.cable_sets == ("original",)
    np.testing.assert_allclose(model.initial_pose, [0, 0, 2, 0, 0, 0], atol=0)
    assert rank(r, model.initial_pose) == 6
    assert any("noise" in a and "placeholder" in a for a in model.assumptions)
    assert any("gravity" in a for a in model.assumptions)


def test_example_spatial_cable_sets(tmp_path):
    b, c = spatial_files(tmp_path)
    default = read_caspr(b, c, ea=1e5)
    assert default.cable_set == "basic_7_cables" and default.robot.num_cables == 7
    assert default.cable_sets == ("basic_7_cables", "basic_8_cables")
    assert any("default_cable_set" in a and "'basic_8_cables'" in a for a in default.assumptions)
    eight = read_caspr(b, c, cable_set="basic_8_cables", ea=1e5)
    r = eight.robot
    np.testing.assert_array_equal(np.asarray(r.anchors), SPATIAL_8_ANCHORS)
    np.testing.assert_array_equal(np.asarray(r.attachments), SPATIAL_8_ATTACHMENTS)  # com at the origin
    assert float(r.platform_mass) == 1.0 and (float(r.tension_min), float(r.tension_max)) == (5.0, 300.0)
    np.testing.assert_array_equal(np.asarray(r.inertia), np.diag([0.0042, 0.0083, 0.0108]))
    np.testing.assert_allclose(eight.initial_pose, [0.5, 0.5, 0.5, 0, 0, 0], atol=0)
    assert rank(r, eight.initial_pose) == 6
    assert not any("cable set" in a for a in eight.assumptions)  # asked for: not an assumption


def test_com_reference_adds_the_com_and_joint_inertia_moves_to_the_com(tmp_path):
    model = read_caspr(*write(tmp_path, body(), cogiro_cables(ref="com")), ea=2e5)
    com = np.array([-0.034, -0.013, 0.264])
    np.testing.assert_allclose(np.asarray(model.robot.attachments), COGIRO_ATTACHMENTS + com, rtol=0, atol=1e-15)
    ipanema2 = body(name="IPAnema 2", q="0 0 3.0 0 0 0", mass="10.0", com="0.0 0.0 0.5", ref="joint",
                    inertia=("3.5", "3.5", "1.0", "0.0", "0.0", "0.0"))
    r = read_caspr(*write(tmp_path, ipanema2, cogiro_cables(), stem="IPAnema_2"), ea=2e5).robot
    np.testing.assert_allclose(np.asarray(r.inertia), np.eye(3), rtol=0, atol=1e-14)
    assert r.name == "IPAnema_2"


def test_linear_spring_K_is_EA_and_ea_overrides(tmp_path):
    files = write(tmp_path, body(), cogiro_cables(kind="cable_linear_spring", extra="<K>13000</K>"))
    model = read_caspr(*files)
    np.testing.assert_array_equal(np.asarray(model.robot.EA), np.full(8, 13000.0))
    assert any("K / length" in a for a in model.assumptions)
    over = read_caspr(*files, ea=5e4)
    np.testing.assert_array_equal(np.asarray(over.robot.EA), np.full(8, 5e4))
    assert any("replaces <K>" in a for a in over.assumptions)


def test_pose_from_q_is_intrinsic_xyz_euler():
    q = [0.1, -0.2, 1.5, 0.3, -0.4, 0.5]
    pose = pose_from_q(q, [1.0, 0.0, 0.0])
    np.testing.assert_allclose(pose[:3], [1.1, -0.2, 1.5], rtol=0, atol=1e-15)
    expected = Rotation.from_euler("XYZ", q[3:]).as_matrix()  # intrinsic X, then Y, then Z: Rx Ry Rz
    np.testing.assert_allclose(np.asarray(so3_exp(pose[3:])), expected, rtol=0, atol=1e-12)


def test_limits_differ_strictest_with_a_note(tmp_path):
    cs = [cable(f"cable {i}", b, p, fmin="100.0" if i != 3 else "150", fmax="5000" if i != 5 else "4000")
          for i, (b, p) in enumerate(COGIRO_CABLES, 1)]
    model = read_caspr(*write(tmp_path, body(), cables_file([("original", cs)])), ea=2e5)
    assert (float(model.robot.tension_min), float(model.robot.tension_max)) == (150.0, 4000.0)
    assert sum("strictest" in a for a in model.assumptions) == 2


def test_convert_command_writes_a_toml_that_loads_and_round_trips(tmp_path, capsys):
    b, c = spatial_files(tmp_path)
    out = tmp_path / "spatial.toml"
    rc = main(["convert", str(b), str(c), "--out", str(out), "--cable-set", "basic_8_cables", "--ea", "1e5",
               "--name", "example-spatial", "--noise", "2e-5", "5e-5", "0.3"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "assumed: gravity [0, 0, -9.81]" in text and "rank 6 of 6" in text and f"wrote {out}" in text
    assert "noise" not in text.split("assumed:", 1)[1]  # given: not an assumption
    robot, pose = load_description(out)  # q_initial written as [platform] reference_pose
    np.testing.assert_array_equal(pose, [0.5, 0.5, 0.5, 0, 0, 0])
    expected = read_caspr(b, c, cable_set="basic_8_cables", ea=1e5, name="example-spatial",
                          noise=(2e-5, 5e-5, 0.3)).robot
    for field in ("anchors", "attachments", "EA", "mass_per_length", "com", "inertia", "gravity"):
        np.testing.assert_array_equal(np.asarray(getattr(robot, field)), np.asarray(getattr(expected, field)))
    assert robot.name == "example-spatial" and float(robot.noise.position) == 2e-5
    assert robot_to_toml(robot, pose) == out.read_text()


@pytest.mark.parametrize("argv_tail, pattern", [
    (["--cable-set", "nope", "--ea", "1e5"],
     r"Example_spatial_cables\.xml: cable set 'nope' not found; the file has 'basic_7_cables', 'basic_8_cables'"),
    ([], r"7 cable\(s\) are <cable_ideal> .*--ea"),
    (["--ea", "1e5", "--noise", "0", "1", "1"], r"--noise 0 1 1: every sigma must be > 0"),
])
def test_convert_command_bad_input_exits_1(tmp_path, capsys, argv_tail, pattern):
    b, c = spatial_files(tmp_path)
    out = tmp_path / "x.toml"
    assert main(["convert", str(b), str(c), "--out", str(out), *argv_tail]) == 1
    assert re.search(pattern, capsys.readouterr().err)
    assert not out.exists()


def test_convert_refuses_to_overwrite_an_input(tmp_path, capsys):
    b, c = spatial_files(tmp_path)
    assert main(["convert", str(b), str(c), "--out", str(c), "--ea", "1e5"]) == 1
    assert "input of this command" in capsys.readouterr().err


PLANAR_XY = body(name="Link 1", joint="PLANAR_XY", q="0.5 0.5 0", mass="10", com="0.0 0.0 0.0",
                 inertia=("10", "10", "10", "0.0", "0.0", "0.0"))
TWO_LINKS = body().replace("</links>", """      <link_rigid num="2" name="R_Y 2">
        <joint type="R_Y" q_initial="0.0"/>
        <physical><mass>1</mass><com_location>0 0 0.5</com_location><end_location>0 0 1</end_location>
          <inertia ref="com"><Ixx>1</Ixx><Iyy>1</Iyy><Izz>1</Izz><Ixy>0</Ixy><Ixz>0</Ixz><Iyz>0</Iyz></inertia>
        </physical><parent><num>1</num><location>0 0 1</location></parent>
      </link_rigid>
    </links>""")


@pytest.mark.parametrize("bodies_text, cables_text, pattern", [
    (PLANAR_XY, cogiro_cables(),
     r"_bodies\.xml: line 6: <link_rigid num='1'> <joint>: type = 'PLANAR_XY': only 'SPATIAL_EULER_XYZ'"),
    (TWO_LINKS, cogiro_cables(), r"_bodies\.xml: line 4: <links>: 2 link\(s\).*multi-link models are not supported"),
    (body(), cogiro_cables().replace(' attachment_reference="joint"', "", 1),
     r"_cables\.xml: line 4: <cable_set id='original'> <cable_ideal name='cable 1'>: missing attribute "
     r"'attachment_reference' of <cable_ideal>"),
    (body(), cogiro_cables().replace("<location>0.5032 -0.4928 0.0</location>", "", 1),
     r"<cable_ideal name='cable 1'> <attachments> element 2: missing element <location>"),
    (body(), cogiro_cables().replace("<location>0.5032 -0.4928 0.0", "<location>0.5032 -0.4928", 1),
     r"element 2 <location>: <location> value '0.5032 -0.4928': expected 3 finite numbers"),
    (body().replace("<Iyz>-1.539</Iyz>", ""), cogiro_cables(), r"<physical> <inertia>: missing element <Iyz>"),
    (body(), cogiro_cables().replace("cable_ideal", "cable_passive_linear_spring", 2),
     r"cable kind <cable_passive_linear_spring> \(name 'cable 1'\) cannot be mapped; supported: <cable_ideal>"),
    (cogiro_cables(), body(), r"_bodies\.xml: root element <cables>, expected <bodies_system>.*swapped"),
    (body().replace("<mass>91.058</mass>", "<mass>-1</mass>"), cogiro_cables(), r"<mass>: value -1.0 must be > 0"),
])
def test_unmappable_or_malformed_models_are_refused(tmp_path, bodies_text, cables_text, pattern):
    files = write(tmp_path, bodies_text, cables_text)
    with pytest.raises(CasprModelError, match=pattern):
        read_caspr(*files, ea=2e5)


def test_caspr_md_documents_every_option():
    """cstiffjax/io/caspr.md (package data) names every option of ``convert``."""
    from pathlib import Path

    from cstiffjax.commands import cli

    doc = (Path(__file__).resolve().parents[1] / "cstiffjax" / "io" / "caspr.md").read_text()
    sub = cli.build_parser()._subparsers._group_actions[0].choices["convert"]
    options = [o for a in sub._actions for o in a.option_strings if o.startswith("--")]
    missing = [o for o in options if f"`{o}" not in doc and o not in ("--help", "--quiet", "--out")]
    assert not missing and len(options) > 8, missing
