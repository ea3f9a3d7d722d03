"""Covariates in the model context and the generated grammar of corrections:
identity at the null value, the term model's Jacobian against finite differences, and the
data-side term model against the same terms compiled as ordinary effects."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cstiffjax import CableLaw
from fitting.effects import build_data, make_model
from fitting.effects import model as M
from fitting.effects.grammar import (
    FORMS,
    TermFamily,
    basis,
    family_terms,
    generate_grammar,
    recorded_lengths,
    scalar_drivers,
)
from fitting.effects.terms_model import Probe, TermModel, chain_basis, probe_sensitivities
from tests.helpers import forget_programs, lab_robot

N = 5


@pytest.fixture(scope="module")
def setup():
    rb, rec = lab_robot("example02")
    rb = dataclasses.replace(rb, name="robot")
    rec = rec.select(np.arange(N))
    return rb, rec, build_data(rec)


def test_context_carries_covariates_index_and_inputs(setup):
    _rb, rec, data = setup
    ctx = data.ctx
    assert data.covariate_names == ("temperature",)
    np.testing.assert_array_equal(np.asarray(ctx.covariates)[:, 0], np.asarray(rec.covariate("temperature")))
    np.testing.assert_array_equal(np.asarray(ctx.index), np.arange(N))
    np.testing.assert_array_equal(np.asarray(ctx.l0), np.asarray(rec.l0))
    np.testing.assert_array_equal(np.asarray(ctx.wrench), np.asarray(rec.wrench))
    d = np.sign(np.diff(np.asarray(rec.l0), axis=0))
    np.testing.assert_array_equal(np.asarray(ctx.direction)[1:], d)
    assert np.all(np.asarray(ctx.direction)[0] == 0)


def test_grammar_is_generated_over_where_form_sharing(setup):
    rb, _rec, data = setup
    fams = generate_grammar(rb, data)
    combos = {(f.where, f.form, f.per_cable) for f in fams}
    for form in FORMS:  # the cable wheres take every form, shared and per cable
        for where in ("l0", "tension"):
            assert (where, form, False) in combos and (where, form, True) in combos
    assert ("load", "gain", False) in combos and ("anchors", "gain", False) in combos
    drivers = scalar_drivers(data)
    assert {"time", "index", "cov:0"} <= set(drivers)  # temperature is a driver
    pose_lin = next(f for f in fams if f.where == "pose" and f.form == "linear")
    assert "t:0" in pose_lin.drivers  # predicted tensions drive measurement terms
    with pytest.raises(ValueError, match="no grammar term"):
        TermFamily("pose", "step", False, (), 6)
    terms = family_terms(fams)
    assert len({t.name for t in terms}) == len(terms) > 150


def _random_params(fam, rb, data, rng, scale=1.0):
    p = {s.name: jnp.asarray(s.null) for s in fam.specs(rb, data)}
    sa = next(s for s in fam.specs(rb, data) if s.name == "a")
    return p | {"a": jnp.asarray(scale * sa.scale * rng.normal(size=sa.shape))}


def test_every_family_is_identity_at_null(setup):
    rb, _rec, data = setup
    rng = np.random.default_rng(0)
    ctx0 = jax.tree_util.tree_map(lambda a: a[2], data.ctx)
    l0, w, pose, t = data.l0[2], data.wrench[2], data.pose[2], data.tensions[2]
    length = recorded_lengths(rb, data)[2]
    assert np.all(length > l0)  # strained cables: a stiffness term moves l0
    for fam in generate_grammar(rb, data):
        null = {s.name: jnp.asarray(s.null) for s in fam.specs(rb, data)}
        l1, w1 = fam.inputs(l0, w, ctx0, null)
        p1, t1 = fam.measure(pose, t, ctx0, null)
        r1 = fam.robot(rb, null)
        s1 = fam.stiffness_inputs(l0, length, ctx0, null) if fam.where == "EA" else l0
        for a, b in ((l1, l0), (w1, w), (p1, pose), (t1, t), (r1.anchors, rb.anchors),
                     (r1.attachments, rb.attachments)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=fam.name)
        np.testing.assert_allclose(np.asarray(s1), np.asarray(l0), rtol=1e-15, err_msg=fam.name)
        # and not the identity away from null (the term does act somewhere)
        p = _random_params(fam, rb, data, rng)
        stiff = (fam.stiffness_inputs(l0, length, ctx0, p),) if fam.where == "EA" else (l0,)
        moved = [fam.inputs(l0, w, ctx0, p), fam.measure(pose, t, ctx0, p), (fam.robot(rb, p).anchors,
                                                                          fam.robot(rb, p).attachments), stiff]
        base = [(l0, w), (pose, t), (rb.anchors, rb.attachments), (l0,)]
        assert any(not np.allclose(np.asarray(a), np.asarray(b)) for mv, bs in zip(moved, base, strict=True)
                   for a, b in zip(mv, bs, strict=True)), fam.name


# a handful of terms covering every where and form (one compile of the transform)
PICK = ("term:l0|cgain|cov:0|shared", "term:l0|step|dir|per_cable", "term:l0|quadratic|-|shared",
        "term:load|gain|-|shared", "term:wrench[2]|linear|cov:0|shared", "term:pose[2]|gain|-|shared",
        "term:pose[0]|linear|t:1|shared", "term:tension|linear|own_l0|per_cable", "term:tension|cgain|time|shared",
        "term:anchors|gain|-|shared", "term:attachments|gain|-|shared", "term:EA|cgain|cov:0|per_cable")


@pytest.fixture(scope="module")
def term_model(setup):
    rb, _rec, data = setup
    terms = {t.name: t for t in family_terms(generate_grammar(rb, data))}
    core = make_model(rb, data, [Probe()])
    return TermModel(core, [terms[k] for k in PICK], rb, data)


def test_term_model_jacobian_matches_finite_differences(setup, term_model):
    rb, _rec, data = setup
    tm = term_model
    rng = np.random.default_rng(1)
    theta = np.zeros(tm.size)
    P = tm.core.size
    theta[P:] = 0.3 * rng.normal(size=tm.size - P)  # away from null: the chain rule at a general point
    r, J, ok = tm.evaluate(theta, rb, data)
    assert ok.all() and J.shape == (r.size, tm.size)
    # the diagnosis asks for few core columns (the free ones): the terms' columns must not
    # depend on that (their probe blocks are computed whatever is asked)
    _, J_few, _ = tm.evaluate(theta, rb, data, core_columns=[0])
    np.testing.assert_allclose(J_few[:, P:], J[:, P:], rtol=1e-10, atol=1e-12 * np.abs(J[:, P:]).max())
    assert not np.any(J_few[:, 1:tm.num_cables])  # EA columns not asked for: 0
    h = 1e-4
    for j in range(P, tm.size):
        e = np.zeros(tm.size)
        e[j] = h
        fd = (tm.evaluate(theta + e, rb, data)[0] - tm.evaluate(theta - e, rb, data)[0]).ravel() / (2 * h)
        scale = np.max(np.abs(fd)) + 1e-12
        assert np.max(np.abs(fd - J[:, j])) < 1e-4 * scale + 1e-6, (j, tm.effects[tm.blocks[-1][0]].name)
        assert scale > 1e-6  # every term moves some residual


def test_screening_basis_matches_autodiff_of_the_transforms(setup, term_model):
    """The closed-form basis used to screen terms equals the autodiff chain rule at a = 0."""
    rb, _rec, data = setup
    tm = term_model
    r, J, _ok = tm.evaluate(np.zeros(tm.size), rb, data)
    n, c = r.shape
    S = probe_sensitivities(tm.core, J)
    for j, t in enumerate(tm.terms):
        qty, B = basis(t.family, data, rb)
        shape = next(s.shape for s in t.family.specs(rb, data) if s.name == "a")
        cols = chain_basis(S, qty, B, n, c)[:, t.entries(shape)] * tm.fam_specs[t.family]["a"].scale
        sl = tm.block_slice(len(tm.core.effects) + j)
        np.testing.assert_allclose(cols, J[:, sl], rtol=1e-8, atol=1e-9 * np.max(np.abs(J[:, sl])), err_msg=t.name)


@pytest.mark.slow  # a second compile (the terms as ordinary effects); the FD test above is the fast check
def test_data_side_terms_equal_the_same_terms_compiled_as_effects(setup, term_model):
    """Input and geometry terms evaluated by transforming the data (TermModel) give the same
    residuals as the same TermFamily compiled into an ordinary ExtendedModel (exact), and
    additive measurement terms too; gain-type measurement terms agree to first order."""
    rb, _rec, data = setup
    tm = term_model
    pick = [t for t in tm.terms if t.family.where in ("l0", "load", "anchors") or (
        t.family.form == "linear" and not t.driver.startswith("t:"))]  # t:i drivers: measured vs predicted
    fams = list(dict.fromkeys(t.family for t in pick))
    ext = make_model(rb, data, fams)
    rng = np.random.default_rng(2)
    theta_tm = np.zeros(tm.size)
    theta_ext = np.zeros(ext.size)
    P = tm.core.size
    for t in pick:
        j = next(k for k, e in enumerate(tm.effects) if e is t)
        sl_tm = tm.block_slice(j)
        v = 0.5 * rng.normal(size=sl_tm.stop - sl_tm.start)
        theta_tm[sl_tm] = v
        fi = fams.index(t.family)
        blk = next(b for b in ext.blocks if b[0] == fi and b[1] == "a")
        ent = t.entries(blk[3])
        theta_ext[blk[2] + ent] = v  # same scale: both use the family's ParamSpec
    r_tm = tm.evaluate(theta_tm, rb, data)[0]
    r_ext = np.asarray(M.residuals_and_jacobian(ext, jnp.asarray(theta_ext), rb, data)[0])
    assert P == tm.core.size
    np.testing.assert_allclose(r_tm, r_ext, atol=1e-6 * np.max(np.abs(r_ext)) + 1e-8)


def test_term_fits_run_at_one_padded_width_with_the_unpadded_result(setup):
    """A term model's host-driven fit pads θ with fixed zeros to a multiple of
    ``HOST_WIDTH`` (:meth:`fitting.diagnosis.discover.DiscoveryFitter.fit_free`): a shared and a
    per-cable term (model sizes differ) compile the host kernels at one width, and each
    result equals the fit at the model's own width."""
    from fitting.calibration import lm
    from fitting.diagnosis.discover import HOST_WIDTH, DiscoveryFitter
    from fitting.effects.fit import fit_masked

    rb, rec, _data = setup
    f = DiscoveryFitter(rb, rec, CableLaw.spring, ())
    w = np.ones(rec.num_samples)
    names = ("term:l0|step|dir|shared", "term:l0|step|dir|per_cable")
    models = [f.model_for([nm]) for nm in names]
    sizes = {m.size for m in models}
    assert len(sizes) == 2 and len({-(-s // HOST_WIDTH) for s in sizes}) == 1  # the case under test
    starts = [(model, f.free_mask(model, [nm])) for nm, model in zip(names, models)]
    starts = [(model, free, np.where(free, model.start, 0.0)) for model, free in starts]
    lm._update_jit.clear_cache()  # count this test's compiles only (the kernels are cheap to rebuild)
    fits = [f.fit_free(model, w, theta0, free) for model, free, theta0 in starts]
    assert lm._update_jit._cache_size() == 1  # one width for both
    for (model, free, theta0), padded in zip(starts, fits):
        plain = fit_masked(f.evaluator(model, w, np.flatnonzero(free)), theta0, None, free, must_succeed=w > 0,
                           on_host=True)
        np.testing.assert_array_equal(padded.free, free)
        assert padded.theta.shape == (model.size,) and padded.J.shape == plain.J.shape
        assert padded.steps == plain.steps > 0 and padded.converged and padded.message == plain.message
        np.testing.assert_allclose(padded.theta, plain.theta, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(padded.chi2, plain.chi2, rtol=1e-10)
        np.testing.assert_allclose(padded.covariance, plain.covariance, rtol=1e-6, atol=1e-12)
    assert lm._update_jit._cache_size() == 3  # unpadded: one program per size (what padding saves)


def test_term_transform_is_a_serialized_program(setup, term_model, tmp_path):
    """The terms' transform (and its Jacobian) has reproducible static arguments (the
    families and an integer layout): it is saved as a serialized program, which a new
    process loads instead of tracing, with the same values as the plain jit."""
    from cstiffjax.runtime import programs
    from fitting.effects import terms_model as T

    rb, _rec, data = setup
    tm = term_model
    v = jnp.asarray(0.3 * np.random.default_rng(2).normal(size=tm.size - tm.core.size))
    args = (tm.families, tm.layout, tm.nulls, rb, data, v)
    plain = T._transform_and_jacobian.jitted(*args)
    programs.set_folder(tmp_path)
    try:
        saved = T._transform_and_jacobian(*args)
        assert len(list(tmp_path.glob("*.jaxexport"))) == 1
        forget_programs()  # a new process's view: loaded from the folder, not traced again
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(programs.export, "export", lambda *a, **k: pytest.fail("traced again, not loaded"))
            loaded = T._transform_and_jacobian(*args)
    finally:
        programs.set_folder(None)
        forget_programs()
    for out in (saved, loaded):
        assert jax.tree_util.tree_structure(out) == jax.tree_util.tree_structure(plain)
        for a, b in zip(jax.tree_util.tree_leaves(out), jax.tree_util.tree_leaves(plain)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-14)
