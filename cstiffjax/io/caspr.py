"""Read a CASPR robot model (a *bodies* XML and a *cables* XML) as a :class:`CableRobot`.

CASPR (the MATLAB cable-robot toolbox of D. Lau et al.) describes a model by two files:
``<bodies_system><links><link_rigid ...>`` (the bodies, their joints and mass properties) and
``<cables default_cable_set=...><cable_set id=...><cable_ideal ...>`` (the cables of one or
more cable sets). :func:`read_caspr` maps one 6-DOF rigid body driven by one or more cables
(straight, or over CASPR's rotating pulleys; fewer than 6 make a suspended robot) onto
formats.md §1 and refuses everything else with an error naming the file, the line, the
element, the value and what is supported. ``caspr.md`` next to this module lists the mapping.

The mapping (all lengths m, masses kg, forces N):

- The platform frame is the frame of CASPR's link 1 (its joint frame): ``com`` is
  ``<com_location>``; ``inertia`` is ``<inertia ref="com">`` as written (CASPR's ``Ixy``,
  ``Ixz``, ``Iyz`` are the off-diagonal entries of the matrix), or ``ref="joint"`` moved to the
  centre of mass (parallel-axis theorem).
- A cable's ``link 0`` location is its ``anchor`` (base frame); its ``link 1`` location is its
  ``attachment``, relative to the joint frame (``attachment_reference="joint"``) or to the
  centre of mass (``"com"``: ``com`` is added).
- A ``<base_rotating_pulley>`` (element 1 of a cable's attachments) is a swivel pulley: CASPR
  puts the pulley centre at ``F + R u`` (``F`` its ``<fixed_location>``, ``R`` its
  ``<pulley_radius>``, ``u`` the unit part of ``P - F`` normal to ``<cable_entry_vector>``),
  makes the cable enter at ``F`` travelling along ``<cable_entry_vector>`` and leave at the
  tangent point on the far side of the pulley: our ``anchor = F``, ``pulley_radius = R``,
  ``pulley_axis`` = the unit entry vector. The lengths agree while the wrap is at most pi
  (CASPR's arc ``R acos(...)`` is then ``R beta``); beyond, CASPR's arc is ``R (2 pi - beta)``.
- ``<force_min>``/``<force_max>`` are ``[limits]``; ``cable_linear_spring``'s ``<K>`` is ``EA``:
  CASPR's stiffness of that cable is ``K / length`` (``CableModelLinearSpring.K``), so ``K`` is
  an axial rigidity in N. ``cable_ideal`` cables are rigid in CASPR: their ``EA`` must be given.
- CASPR's gravity is fixed at 9.81 m/s² along -z of the base frame: the default ``gravity``.
- A CASPR pose ``q`` of ``SPATIAL_EULER_XYZ`` is our pose ``[r_parent + q[:3], log(Rx Ry Rz)]``
  (:func:`pose_from_q`).

What CASPR does not hold (noise sigmas, cable mass per length, EA of ideal cables) comes from
the caller; every value not read from the files is listed in :attr:`CasprModel.assumptions`.
"""

import math
import xml.parsers.expat
from pathlib import Path
from typing import NamedTuple
from xml.etree.ElementTree import Element, TreeBuilder

import numpy as np

from cstiffjax.core.errors import RobotFileError
from cstiffjax.core.lie import log as _so3_log
from cstiffjax.io.robot import CableRobot, Noise

SPATIAL_JOINT = "SPATIAL_EULER_XYZ"
CABLE_KINDS = ("cable_ideal", "cable_linear_spring")
PULLEY = "base_rotating_pulley"  # CASPR's BaseRotatingPulleyAttachment: our swivel pulley (module docstring)
GRAVITY = (0.0, 0.0, -9.81)  # CASPR's SystemModel.GRAVITY_CONSTANT, along -z of the base frame
DEFAULT_NOISE = (1e-4, 1e-3, 1.0)  # m, rad, N: placeholders for formats.md §1 [noise]; always reported
_INERTIA = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
# Size limits, checked at the reader's entry: a model file larger than MAX_FILE_BYTES is refused
# before it is read; a cables file is refused at its first cable element beyond MAX_CABLES (all
# cable sets together), before the rest is parsed. A CASPR model of one platform has a few dozen
# cables of ~400 bytes each; the largest allowed file converts in well under a minute.
MAX_FILE_BYTES = 32 * 2**20
MAX_CABLES = 50_000


class CasprModelError(RobotFileError):
    """A CASPR model file that cannot be read or mapped: the message names the file, the line,
    the element, the value and what is supported."""


class CasprModel(NamedTuple):
    """The result of :func:`read_caspr`.

    - ``robot``: the :class:`CableRobot`.
    - ``cable_set``: the id of the cable set read; ``cable_sets``: every id in the file.
    - ``initial_pose``: ``q_initial`` of the joint as our pose (6,) m / rad, or ``None``.
    - ``assumptions``: one line per value that did not come from the files.
    """

    robot: CableRobot
    cable_set: str
    cable_sets: tuple[str, ...]
    initial_pose: np.ndarray | None
    assumptions: tuple[str, ...]


class _Xml:
    """One parsed XML file with the line of each element, for messages."""

    def __init__(self, path: Path, kind: str, root_tag: str):
        self.path = Path(path)
        try:
            size = self.path.stat().st_size
            if size > MAX_FILE_BYTES:
                raise CasprModelError(f"{self.path}: CASPR {kind} file of {size} bytes ({size / 2**20:.1f} MiB): "
                                      f"larger than the reader's limit of {MAX_FILE_BYTES} bytes "
                                      f"({MAX_FILE_BYTES / 2**20:g} MiB, cstiffjax.io.caspr.MAX_FILE_BYTES); "
                                      "a model of one platform is a few kB per cable")
            data = self.path.read_bytes()
        except OSError as e:
            raise CasprModelError(f"{self.path}: cannot read CASPR {kind} file: {e.strerror}") from None
        builder, self.lines = TreeBuilder(), {}
        parser = xml.parsers.expat.ParserCreate()
        cables = 0

        def start(tag, attrs):
            nonlocal cables
            if kind == "cables" and tag.startswith("cable_") and tag != "cable_set":
                cables += 1
                if cables > MAX_CABLES:
                    raise CasprModelError(f"{self.path}: line {parser.CurrentLineNumber}: <{tag}>: more than "
                                          f"{MAX_CABLES} cables in the file, the reader's limit "
                                          "(cstiffjax.io.caspr.MAX_CABLES); the rest is not read")
            self.lines[id(el := builder.start(tag, attrs))] = parser.CurrentLineNumber
            return el

        parser.StartElementHandler, parser.EndElementHandler = start, builder.end
        parser.CharacterDataHandler = builder.data
        try:
            parser.Parse(data, True)
        except xml.parsers.expat.ExpatError as e:
            raise CasprModelError(f"{self.path}: not well-formed XML: {e}") from None
        self.root = builder.close()
        if self.root.tag != root_tag:
            hint = " (bodies and cables files swapped?)" if self.root.tag in ("bodies_system", "cables") else ""
            raise CasprModelError(f"{self.path}: root element <{self.root.tag}>, expected <{root_tag}> "
                                  f"(a CASPR {kind} file){hint}")

    def fail(self, el: Element, where: str, msg: str):
        raise CasprModelError(f"{self.path}: line {self.lines.get(id(el), '?')}: {where}: {msg}")

    def child(self, el: Element, tag: str, where: str) -> Element:
        found = el.find(tag)
        if found is None:
            self.fail(el, where, f"missing element <{tag}>")
        return found

    def attr(self, el: Element, name: str, where: str) -> str:
        value = el.get(name)
        if value is None or not value.strip():
            self.fail(el, where, f"missing attribute '{name}' of <{el.tag}>")
        return value.strip()

    def numbers(self, el: Element, where: str, n: int, text: str | None = None) -> np.ndarray:
        text = (el.text or "") if text is None else text
        parts = text.split()
        try:
            values = np.array([float(p) for p in parts])
        except ValueError:
            values = None
        if values is None or values.shape != (n,) or not np.all(np.isfinite(values)):
            self.fail(el, where, f"<{el.tag}> value {text.strip()!r}: expected {n} finite number"
                                 f"{'s' if n > 1 else ''} separated by spaces")
        return values

    def number(self, parent: Element, tag: str, where: str) -> float:
        return float(self.numbers(self.child(parent, tag, where), f"{where} <{tag}>", 1)[0])


class _Body(NamedTuple):
    mass: float
    com: np.ndarray
    inertia: np.ndarray
    parent_location: np.ndarray
    q_initial: np.ndarray | None
    name: str


def _read_body(path) -> _Body:
    x = _Xml(path, "bodies", "bodies_system")
    links = x.child(x.root, "links", "<bodies_system>")
    bodies = list(links)
    if not bodies:
        x.fail(links, "<links>", "no link: a cable robot needs one <link_rigid> (the platform)")
    if len(bodies) > 1 or bodies[0].tag != "link_rigid":
        names = ", ".join(f"<{b.tag} num={b.get('num')!r}>" for b in bodies[:3]) + (", ..." if len(bodies) > 3 else "")
        x.fail(links, "<links>", f"{len(bodies)} link(s): {names}; only a single rigid body (one <link_rigid>, "
                                 f"the platform) maps to a robot description: multi-link models are not supported")
    link = bodies[0]
    where = f"<link_rigid num={link.get('num')!r}>"
    if x.attr(link, "num", where) != "1":
        x.fail(link, where, f"attribute num = {link.get('num')!r}: the platform must be link 1")
    joint = x.child(link, "joint", where)
    jtype = x.attr(joint, "type", f"{where} <joint>")
    if jtype != SPATIAL_JOINT:
        x.fail(joint, f"{where} <joint>", f"type = {jtype!r}: only {SPATIAL_JOINT!r} (a 6-DOF platform) maps to a "
                                          "'cdpr' robot; planar, spherical, revolute, universal and translational "
                                          "joints are not supported")
    q_initial = None
    if joint.get("q_initial") is not None:
        q_initial = x.numbers(joint, f"{where} <joint> attribute q_initial", 6, joint.get("q_initial"))
    physical = x.child(link, "physical", where)
    pw = f"{where} <physical>"
    mass = x.number(physical, "mass", pw)
    if not mass > 0:
        x.fail(physical.find("mass"), f"{pw} <mass>", f"value {mass!r} must be > 0 (kg)")
    com = x.numbers(x.child(physical, "com_location", pw), f"{pw} <com_location>", 3)
    inertia_el = x.child(physical, "inertia", pw)
    iw = f"{pw} <inertia>"
    ref = x.attr(inertia_el, "ref", iw)
    if ref not in ("com", "joint"):
        x.fail(inertia_el, iw, f"attribute ref = {ref!r}: allowed 'com' or 'joint'")
    xx, yy, zz, xy, xz, yz = (x.number(inertia_el, k, iw) for k in _INERTIA)
    inertia = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])
    if ref == "joint":  # about the joint origin -> about the centre of mass
        inertia = inertia - mass * (com @ com * np.eye(3) - np.outer(com, com))
    if np.linalg.eigvalsh(inertia).min() <= 0:
        x.fail(inertia_el, iw, f"the inertia about the centre of mass {inertia.tolist()} (kg m^2) is not "
                               "positive definite")
    parent = x.child(link, "parent", where)
    num = x.child(parent, "num", f"{where} <parent>")
    if (num.text or "").strip() != "0":
        x.fail(num, f"{where} <parent> <num>", f"value {(num.text or '').strip()!r}: the platform's parent "
                                               "must be the base, 0")
    location = x.numbers(x.child(parent, "location", f"{where} <parent>"), f"{where} <parent> <location>", 3)
    return _Body(mass, com, inertia, location, q_initial, link.get("name") or "")


class _Cable(NamedTuple):
    name: str
    kind: str
    anchor: np.ndarray
    attachment: np.ndarray
    K: float | None
    force_min: float | None
    force_max: float | None
    pulley_radius: float  # m; 0: a straight cable
    pulley_axis: np.ndarray  # unit cable_entry_vector; zeros: a straight cable


def _read_cables(path, cable_set: str | None, com: np.ndarray):
    x = _Xml(path, "cables", "cables")
    sets = {}
    for s in x.root:
        if s.tag != "cable_set":
            x.fail(s, "<cables>", f"unknown element <{s.tag}>; allowed: <cable_set>")
        sid = x.attr(s, "id", "<cable_set>")
        if sid in sets:
            x.fail(s, f"<cable_set id={sid!r}>", "a second cable set with this id")
        sets[sid] = s
    if not sets:
        x.fail(x.root, "<cables>", "no <cable_set>")
    ids = ", ".join(map(repr, sets))
    how = "given"
    if cable_set is None:
        default = x.root.get("default_cable_set")
        cable_set, how = (default, "the file's default_cable_set") if default else (next(iter(sets)), "the first")
        if cable_set not in sets:
            x.fail(x.root, "<cables>", f"default_cable_set = {cable_set!r} names no cable set; the file has {ids}")
    elif cable_set not in sets:
        raise CasprModelError(f"{x.path}: cable set {cable_set!r} not found; the file has {ids}")
    cables = [_read_cable(x, c, f"<cable_set id={cable_set!r}>", com) for c in sets[cable_set]]
    return cable_set, tuple(sets), cables, how


def _read_cable(x: _Xml, c: Element, set_where: str, com: np.ndarray) -> _Cable:
    if c.tag not in CABLE_KINDS:
        x.fail(c, set_where, f"cable kind <{c.tag}> (name {c.get('name')!r}) cannot be mapped; supported: "
                             f"{', '.join(f'<{k}>' for k in CABLE_KINDS)} (actuated straight cables)")
    where = f"{set_where} <{c.tag}>"
    name = x.attr(c, "name", where)
    where = f"{set_where} <{c.tag} name={name!r}>"
    ref = x.attr(c, "attachment_reference", where)
    if ref not in ("com", "joint"):
        x.fail(c, where, f"attribute attachment_reference = {ref!r}: allowed 'com' or 'joint'")
    props = c.find("properties")
    pw = f"{where} <properties>"
    K = None
    if c.tag == "cable_linear_spring":
        K = x.number(x.child(c, "properties", where), "K", pw)
        if not K > 0:
            x.fail(props.find("K"), f"{pw} <K>", f"value {K!r} must be > 0 (N: CASPR's stiffness is K / length)")
    limits = [None if props is None or props.find(k) is None else x.number(props, k, pw)
              for k in ("force_min", "force_max")]
    attachments = x.child(c, "attachments", where)
    points, radius, axis = {}, 0.0, np.zeros(3)
    for i, a in enumerate(attachments, 1):
        aw = f"{where} <attachments> element {i}"
        if a.tag == PULLEY and i == 1:
            points["0"], radius, axis = _read_pulley(x, a, aw)
            continue
        if a.tag != "attachment":
            first = " (only as element 1, on the base)" if a.tag == PULLEY else ""
            x.fail(a, aw, f"<{a.tag}> cannot be mapped{first}: supported are straight cables between two "
                          f"<attachment>s and cables from a <{PULLEY}> (element 1) to an <attachment> on link 1 "
                          "(no screw-drive pulleys, no via points)")
        link = (x.child(a, "link", aw).text or "").strip()
        if link not in ("0", "1") or link in points:
            x.fail(a.find("link"), f"{aw} <link>", f"value {link!r}: a cable must join link 0 (the base, or a "
                                                   f"<{PULLEY}>) and link 1 (the platform), once each")
        points[link] = x.numbers(x.child(a, "location", aw), f"{aw} <location>", 3)
    if len(points) != 2 or len(attachments) != 2:
        x.fail(attachments, f"{where} <attachments>", f"{len(attachments)} attachment(s): a cable has exactly "
                                                      f"two, on link 0 (or a <{PULLEY}>) and on link 1")
    attachment = points["1"] + (com if ref == "com" else 0.0)
    return _Cable(name, c.tag, points["0"], attachment, K, *limits, radius, axis)


def _read_pulley(x: _Xml, a: Element, where: str) -> tuple[np.ndarray, float, np.ndarray]:
    """A ``<base_rotating_pulley>`` as ``(anchor m, pulley_radius m, pulley_axis)`` (module
    docstring: CASPR's entry point, radius and entry direction are our swivel pulley's)."""
    anchor = x.numbers(x.child(a, "fixed_location", where), f"{where} <fixed_location>", 3)
    radius = x.number(a, "pulley_radius", where)
    if not radius > 0:
        x.fail(a.find("pulley_radius"), f"{where} <pulley_radius>", f"value {radius!r} must be > 0 (m)")
    entry_el = x.child(a, "cable_entry_vector", where)
    entry = x.numbers(entry_el, f"{where} <cable_entry_vector>", 3)
    norm = float(np.linalg.norm(entry))
    if not norm > 0:
        x.fail(entry_el, f"{where} <cable_entry_vector>", f"value {entry.tolist()}: the direction in which the "
                                                          "cable enters the pulley must not be zero")
    return anchor, radius, entry / norm


def pose_from_q(q, parent_location) -> np.ndarray:
    """Our pose ``[x, y, z, rx, ry, rz]`` (m, rad; rotation vector) of a CASPR
    ``SPATIAL_EULER_XYZ`` joint coordinate ``q = [x, y, z, a, b, c]`` whose joint frame sits at
    ``parent_location`` (m) of the base: position ``parent_location + q[:3]``, rotation
    ``Rx(a) Ry(b) Rz(c)``."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([np.asarray(parent_location, float) + q[:3], np.asarray(_so3_log(_rotation_xyz(q[3:])))])


def _rotation_xyz(angles) -> np.ndarray:
    """``Rx(a) Ry(b) Rz(c)`` (3, 3) of CASPR's ``SPATIAL_EULER_XYZ`` angles ``[a, b, c]``, rad."""
    rotations = []
    for axis, angle in zip(range(3), angles, strict=True):
        c, s = math.cos(angle), math.sin(angle)
        i, j = (axis + 1) % 3, (axis + 2) % 3  # cyclic: Ry has +sin at [0, 2]
        R = np.eye(3)
        R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
        rotations.append(R)
    return rotations[0] @ rotations[1] @ rotations[2]


def read_caspr(bodies_path, cables_path, *, cable_set: str | None = None, ea: float | None = None,
               name: str | None = None, gravity=None, noise=None, mass_per_length: float = 0.0,
               tension_limits=None) -> CasprModel:
    """Read a CASPR bodies XML and cables XML as a :class:`CableRobot` (formats.md §1).

    **Arguments:**

    - ``bodies_path``, ``cables_path``: CASPR's ``*_bodies.xml`` and ``*_cables.xml``.
    - ``cable_set``: the ``<cable_set id>`` to read; ``None``: the file's ``default_cable_set``,
      else its first cable set.
    - ``ea``: axial stiffness E·A of every cable, N (required when a cable is ``cable_ideal``;
      overrides ``<K>`` of ``cable_linear_spring`` cables).
    - ``name``: robot name; ``None``: the bodies file name without ``_bodies.xml``.
    - ``gravity`` (3,) m/s², base frame; ``None``: CASPR's ``[0, 0, -9.81]``.
    - ``noise``: ``(position m, rotation rad, tension N)`` sigmas; ``None``: :data:`DEFAULT_NOISE`.
    - ``mass_per_length``: kg/m of every cable (CASPR's cables are massless: default 0).
    - ``tension_limits``: ``(min, max)`` N overriding the files' ``force_min``/``force_max``.

    **Returns:** a :class:`CasprModel`.

    **Raises:** :class:`CasprModelError` naming the file, line, element, value and what is
    supported (a multi-link or non-spatial model, a screw-drive pulley or a via point, an empty or
    unknown cable set, a missing element or attribute), or naming the file, its size and
    :data:`MAX_FILE_BYTES` (checked before it is read), or the line of the first cable beyond
    :data:`MAX_CABLES` (parsing stops there); ``ValueError`` for a bad argument.
    """
    bodies_path, cables_path = Path(bodies_path), Path(cables_path)
    body = _read_body(bodies_path)
    chosen, sets, cables, how = _read_cables(cables_path, cable_set, body.com)
    notes = []
    if not cables:
        raise CasprModelError(f"{cables_path}: cable set {chosen!r} has no cable; a robot needs one or more "
                              f"(cable sets in the file: {', '.join(map(repr, sets))})")
    if cable_set is None and len(sets) > 1:
        notes.append(f"cable set {chosen!r} ({how}; others: {', '.join(repr(s) for s in sets if s != chosen)})")
    ideal = [c.name for c in cables if c.K is None]
    if ea is not None:
        if not (math.isfinite(ea) and ea > 0):
            raise ValueError(f"EA = {ea!r} must be a finite number > 0 (N)")
        EA = np.full(len(cables), float(ea))
        overridden = [c.name for c in cables if c.K is not None]
        notes.append(f"EA = {ea:g} N for every cable (given)" +
                     (f"; replaces <K> of {', '.join(overridden)}" if overridden else ""))
    elif ideal:
        raise CasprModelError(f"{cables_path}: cable set {chosen!r}: {len(ideal)} cable(s) are <cable_ideal> "
                              f"({', '.join(ideal)}): CASPR's ideal cables are rigid and hold no stiffness, and "
                              f"every stiffness result depends on it; give the axial stiffness E*A of the "
                              f"cables in N (--ea N, or ea=): Young's modulus x cross-section area, e.g. from "
                              f"the cable's datasheet")
    else:
        EA = np.array([c.K for c in cables])
        notes.append("EA = CASPR's <K> of each cable_linear_spring (CASPR's stiffness is K / length, so K is E*A, N)")
    if tension_limits is not None:
        tmin, tmax = map(float, tension_limits)
        notes.append(f"tension limits [{tmin:g}, {tmax:g}] N (given)")
    else:
        tmin, tmax = _limits(cables, notes)
    if not (0 <= tmin < tmax):
        raise CasprModelError(f"{cables_path}: tension limits [{tmin:g}, {tmax:g}] N: need 0 <= min < max")
    if gravity is None:
        gravity = GRAVITY
        notes.append("gravity [0, 0, -9.81] m/s^2 (CASPR's fixed gravity, -z of the base frame)")
    if noise is None:
        noise = DEFAULT_NOISE
        notes.append(f"noise sigmas position {noise[0]:g} m, rotation {noise[1]:g} rad, tension {noise[2]:g} N "
                     "(placeholders: CASPR has none; set them from your sensors)")
    if mass_per_length == 0.0:
        notes.append("massless cables (mass_per_length = 0, as CASPR's cables)")
    if name is None:
        name = bodies_path.name.removesuffix(".xml").removesuffix("_bodies") or "caspr"
    initial = None if body.q_initial is None else pose_from_q(body.q_initial, body.parent_location)
    if np.any(body.parent_location != 0):
        notes.append(f"the platform frame sits at {body.parent_location.tolist()} m of the base when CASPR's q = 0: "
                     "our pose position = that + q[:3]")
    m = len(cables)
    robot = CableRobot(
        anchors=np.array([c.anchor for c in cables]), attachments=np.array([c.attachment for c in cables]),
        EA=EA, mass_per_length=np.full(m, float(mass_per_length)), platform_mass=body.mass, com=body.com,
        inertia=body.inertia, gravity=np.asarray(gravity, float), noise=Noise(*map(float, noise)),
        tension_min=tmin, tension_max=tmax, name=name, **_pulleys(cables, body, notes))
    return CasprModel(robot, chosen, sets, initial, tuple(notes))


def _limits(cables: list[_Cable], notes: list[str]) -> tuple[float, float]:
    """One ``[limits]`` pair from the cables' ``force_min``/``force_max`` (the strictest when they
    differ, which ``notes`` says; ``0``/``inf`` when absent)."""
    out = []
    for k, (pick, absent) in (("force_min", (max, 0.0)), ("force_max", (min, math.inf))):
        values = [getattr(c, k) for c in cables]
        given = [v for v in values if v is not None]
        if len(given) < len(values):
            missing = [c.name for c, v in zip(cables, values, strict=True) if v is None]
            notes.append(f"no <{k}> for {', '.join(missing)}: taken as {pick(given) if given else absent:g} N")
        value = pick(given) if given else absent
        if len(set(given)) > 1:
            notes.append(f"<{k}> differs between cables ({min(given):g}..{max(given):g} N): one limit for all, "
                         f"the strictest {value:g} N")
        out.append(value)
    return out[0], out[1]


def _pulleys(cables: list[_Cable], body: _Body, notes: list[str]) -> dict:
    """The :class:`CableRobot` pulley fields of the cables that run over a ``<base_rotating_pulley>``
    (none: ``{}``, a version-1 description). ``swivel_zero``, which CASPR does not hold, is the
    pulley plane's direction ``u`` (formats.md §1) at CASPR's ``q_initial`` (or ``q = 0``), so
    that a swivel encoder would read 0 there; ``notes`` says so."""
    over = [c.pulley_radius > 0 for c in cables]
    if not any(over):
        return {}
    q = np.zeros(6) if body.q_initial is None else body.q_initial
    position, R = body.parent_location + q[:3], _rotation_xyz(q[3:])
    zeros, unset = np.zeros((len(cables), 3)), []
    for i, c in enumerate(cables):
        if c.pulley_radius > 0:
            d = position + R @ c.attachment - c.anchor
            d_p = d - (d @ c.pulley_axis) * c.pulley_axis
            if np.linalg.norm(d_p) > 1e-9 * max(1.0, float(np.linalg.norm(d))):
                zeros[i] = d_p / np.linalg.norm(d_p)
            else:
                unset.append(c.name)
    where = "q = 0" if body.q_initial is None else "CASPR's q_initial"
    notes.append(f"swivel_zero of each pulley: its swivel direction at {where} (CASPR has no swivel encoders)"
                 + (f"; none for {', '.join(unset)} (the attachment is on the swivel axis there)" if unset else ""))
    return {"pulley_radius": np.array([c.pulley_radius for c in cables]),
            "pulley_axis": np.array([c.pulley_axis for c in cables]), "swivel_zero": zeros}
