"""Training a generator with the stability loss (stablelego_jax.train)."""
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stablelego_jax.blas import one_blas_thread
from stablelego_jax.cli import main
from stablelego_jax.train import net
from stablelego_jax.train import train as T
from stablelego_jax.train.shapes import procedural_shape

# the tests call the jitted training step themselves (make test runs each
# test file on one xdist worker, so the compiled step is shared)
pytestmark = pytest.mark.usefixtures("x64")

TINY = {"n_procedural": 6, "mesh_dir": None, "steps": 4, "batch": 2, "n_pad": 16, "m_pad": 512, "p_pad": 32,
        "competitors": 4, "random_competitors": 2, "checkpoint_every": 2, "eval_every": 100, "eval_train": 2,
        "eval_heldout": False, "log_every": 1, "width": 8, "lam": 50.0, "lr": 0.01}


def _cfg(tmp_path, **kw):
    path = tmp_path / "cfg.json"
    path.write_text(json.dumps(dict(TINY, **kw)))
    return T.load_config(str(path))


def _batch(cfg, kinds=("cantilever", "tee")):
    shapes = [procedural_shape(i, kind=k) for i, k in enumerate(kinds)]
    return T.Arrays(shapes, cfg["crop"], cfg["grid"])


def test_loss_decreases_and_stability_gradient_reaches_params(tmp_path):
    cfg = _cfg(tmp_path)
    probs_fn, step_fn, opt, terms, grad_fn = T.make_fns(cfg)
    arr = _batch(cfg)
    params = T.initial_params(cfg, 0)
    rng = np.random.default_rng(0)
    with one_blas_thread():
        p = np.asarray(probs_fn(params, arr.x, arr.valid))
        sub = T.batch_subsets(p, arr.valid, cfg, rng)
        args = (arr.x, arr.valid, arr.target, *sub)
        # the stability term's gradient reaches every layer of the generator:
        # grad(total at lam) - grad(total at lam = 0) = grad(lam * stability)
        lam, bw = np.float64(cfg["lam"]), np.float64(0.1)
        _, aux, g1 = grad_fn(params, lam, bw, *args)
        _, _, g0 = grad_fn(params, np.float64(0.0), bw, *args)
        assert float(aux[2]) > 0.0
        g = jax.tree_util.tree_map(lambda a, b: a - b, g1, g0)
        for w, b in g:
            assert np.isfinite(np.asarray(w)).all() and np.isfinite(np.asarray(b)).all()
            assert float(jnp.abs(w).sum()) > 0.0
        # a few steps on a fixed batch and subset lower the total loss
        opt_state = opt.init(params)
        losses = []
        for _ in range(10):
            params, opt_state, loss, _ = step_fn(params, opt_state, lam, bw, *args[:3], sub)
            losses.append(float(loss))
    assert np.isfinite(losses).all()
    assert losses[-1] < 0.8 * losses[0]


def test_lambda_zero_skips_the_stability_term_with_the_same_loss_and_gradient(tmp_path):
    """lam 0: a graph without the soft solves, whose loss and gradient are
    those of the full graph at lam 0 (there: fidelity + bw binarize + 0 x a
    solved stability term), and a run that logs the term as not computed."""
    full = _cfg(tmp_path)
    off = dict(full, lam=0.0)
    arr = _batch(full)
    params = T.initial_params(full, 0)
    bw = np.float64(0.1)
    with one_blas_thread():
        probs_fn, _, _, _, grad_full = T.make_fns(full)
        p = np.asarray(probs_fn(params, arr.x, arr.valid))
        sub = T.batch_subsets(p, arr.valid, full, np.random.default_rng(0))
        loss1, aux1, g1 = grad_full(params, np.float64(0.0), bw, arr.x, arr.valid, arr.target, *sub)
        _, _, _, _, grad_off = T.make_fns(off)
        loss0, aux0, g0 = grad_off(params, np.float64(0.0), bw, arr.x, arr.valid, arr.target,
                                   *T.Subset(None, None, None, None))
    assert float(aux1[2]) > 0.0 and np.isnan(float(aux0[2])) and np.isnan(float(aux0[3]))
    assert abs(float(loss0) - float(loss1)) <= 1e-12 * abs(float(loss1))
    np.testing.assert_allclose(float(aux0[0]), float(aux1[0]), rtol=1e-12)
    for (w0, b0), (w1, b1) in zip(g0, g1):
        np.testing.assert_allclose(np.asarray(w0), np.asarray(w1), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(np.asarray(b0), np.asarray(b1), rtol=1e-10, atol=1e-12)
    # a run: history rows log the term as null, the checkpoint is written
    out = tmp_path / "run0"
    with one_blas_thread():
        _, history = T.train(dict(off, steps=2), str(out))
    rows = [h for h in history if not h.get("eval")]
    assert rows and all(h["stability"] is None and h["converged"] is None for h in rows)
    assert all(np.isfinite(h["loss"]) for h in rows)
    assert (out / "checkpoint.npz").exists()


@pytest.mark.slow
def test_subsets_solved_one_at_a_time_give_the_batched_loss_and_gradient(tmp_path):
    """stability_solves "each" (each subset on its own rung of the ladder,
    its own compiled solve) and "batch" (one padded shape under vmap): the
    same subsets, the same loss terms and gradient to rounding; the
    problems of "each" hold the subset's bricks first, then padding."""
    each, batch = _cfg(tmp_path), _cfg(tmp_path, stability_solves="batch")
    assert each["stability_solves"] == "each"  # the default
    arr = _batch(each, kinds=("cantilever", "tee"))
    params = T.initial_params(each, 0)
    lam, bw = np.float64(each["lam"]), np.float64(0.1)
    out = {}
    # absent_below: both paths drop the same placements (4 of one subset at initialisation, weights 0.10)
    drop = dict(each, absent_below=0.12), dict(batch, absent_below=0.12)
    with one_blas_thread():
        for name, cfg in (("each", each), ("batch", batch), ("each drop", drop[0]), ("batch drop", drop[1])):
            probs_fn, _, _, terms, grad_fn = T.make_fns(cfg)
            p = np.asarray(probs_fn(params, arr.x, arr.valid))
            sub = T.batch_subsets(p, arr.valid, cfg, np.random.default_rng(0), arr.span)
            # the loss terms alone: once, against the gradient's (the batched graph's terms would compile again)
            out[name] = (sub, grad_fn(params, lam, bw, arr.x, arr.valid, arr.target, *sub),
                         terms(params, arr.x, arr.valid, arr.target, *sub) if name == "each" else None)
    (se, (le, ae, ge), te), (sb, (lb, ab, gb), tb) = out["each"], out["batch"]
    np.testing.assert_array_equal(se.fi, sb.fi)
    assert isinstance(se.prob, tuple) and len(se.prob) == 2
    for j, prob in enumerate(se.prob):
        n = int(se.mask[j].sum())
        assert prob.mass.shape[0] >= n and np.asarray(prob.brick_mask)[:n].all()
        assert not np.asarray(prob.brick_mask)[n:].any()
    assert float(ae[2]) > 0.0 and float(ae[3]) == 1.0
    np.testing.assert_allclose(float(le), float(lb), rtol=1e-9)
    np.testing.assert_allclose([float(a) for a in ae], [float(a) for a in ab], rtol=1e-9)
    np.testing.assert_allclose([float(a) for a in te], [float(a) for a in ae], rtol=1e-9)
    scale = max(float(jnp.abs(w).max()) for w, _ in gb)
    for (w1, b1), (w2, b2) in zip(ge, gb):
        np.testing.assert_allclose(np.asarray(w1), np.asarray(w2), rtol=1e-7, atol=1e-9 * scale)
        np.testing.assert_allclose(np.asarray(b1), np.asarray(b2), rtol=1e-7, atol=1e-9 * scale)
    (_, (lde, ade, _), _), (_, (ldb, adb, _), _) = out["each drop"], out["batch drop"]
    assert float(ade[2]) > 0.0 and abs(float(ade[2]) - float(ae[2])) > 1e-3 * float(ae[2])
    np.testing.assert_allclose(float(lde), float(ldb), rtol=1e-9)
    np.testing.assert_allclose([float(a) for a in ade], [float(a) for a in adb], rtol=1e-9)


def test_subsets_solved_in_threads_give_the_same_numbers(tmp_path, monkeypatch):
    """solve_jobs 2: the batch's subsets are solved two at a time, each on a
    thread of its own, and the loss terms and gradient are bit for bit those
    of one at a time; a resumed run may change it (a HOW key), a negative
    count is refused."""
    import threading

    cfg1 = _cfg(tmp_path, batch=4, solve_jobs=1)
    cfg2 = dict(cfg1, solve_jobs=2)
    arr = _batch(cfg1, kinds=("cantilever", "tee", "bridge", "table"))
    params = T.initial_params(cfg1, 0)
    lam, bw = np.float64(cfg1["lam"]), np.float64(0.1)
    threads = set()
    real_compiled = T.compiled

    def counting(*args, **kw):
        threads.add(threading.get_ident())
        return real_compiled(*args, **kw)

    monkeypatch.setattr(T, "compiled", counting)  # the thread that runs each subset's solve
    out = {}
    with one_blas_thread():
        for name, cfg in (("one", cfg1), ("two", cfg2)):
            probs_fn, _, _, _, grad_fn = T.make_fns(cfg)
            p = np.asarray(probs_fn(params, arr.x, arr.valid))
            sub = T.batch_subsets(p, arr.valid, cfg, np.random.default_rng(0), arr.span)
            assert len(sub.prob) == 4
            threads.clear()
            out[name] = grad_fn(params, lam, bw, arr.x, arr.valid, arr.target, *sub)
            out[name + " threads"] = set(threads)
    assert out["one threads"] == {threading.get_ident()}
    assert len(out["two threads"]) == 2 and threading.get_ident() not in out["two threads"]
    (l1, a1, g1), (l2, a2, g2) = out["one"], out["two"]
    assert float(a1[2]) > 0.0
    assert float(l1) == float(l2) and [float(a) for a in a1] == [float(a) for a in a2]
    for x1, x2 in zip(jax.tree_util.tree_leaves(g1), jax.tree_util.tree_leaves(g2)):
        np.testing.assert_array_equal(np.asarray(x1), np.asarray(x2))
    assert T.config_diff(cfg1, cfg2) == [] and T.solve_jobs(cfg2) == 2 and T.solve_jobs(dict(cfg1, solve_jobs=0)) >= 1
    with pytest.raises(T.ConfigError, match="cfg.json.*solve_jobs"):
        _cfg(tmp_path, solve_jobs=-1)


def test_nearly_absent_placements_are_dropped_and_the_subset_converges():
    """A cluster of nearly absent bricks (weight 1e-17) on a layout: the soft
    interior point does not centre on it as it is; with ``absent_below``
    (:func:`present`) those bricks leave the problem, the solve converges,
    and loss and gradient are those of the layout without them (the
    dropped bricks' gradient 0)."""
    from stablelego_jax import load_layout
    from stablelego_jax.loss import soft_report, stability_loss
    from stablelego_jax.soft import soft_problem
    from stablelego_jax.solvers.problem import pad_soft

    from conftest import EXAMPLES

    lay = load_layout(os.path.join(EXAMPLES, "stablelego", "external_weight_fail.json"))
    prob = pad_soft(soft_problem(lay), 8, 256, 32)
    n = lay.n
    top = np.argsort(-np.asarray(prob.level)[:n], kind="stable")[:3]
    w = np.zeros(8)
    w[:n] = 1.0
    w[top] = 1e-17
    kept = [i for i in range(n) if i not in top]
    small = pad_soft(soft_problem(lay.subset(kept)), 8, 256, 32)
    w_small = np.zeros(8)
    w_small[: len(kept)] = 1.0

    def loss(w, prob, below):
        w, prob = T.present(w, prob, below)
        return stability_loss(w, None, prob)

    def converged(w, prob, below):
        w, prob = T.present(w, prob, below)
        return soft_report(w, None, prob).converged

    vg = jax.jit(jax.value_and_grad(loss), static_argnums=2)
    conv = jax.jit(converged, static_argnums=2)
    with one_blas_thread():
        assert not bool(conv(w, prob, 0.0))  # the cluster as it is: not centred
        assert bool(conv(w, prob, 1e-6))
        v, g = vg(w, prob, 1e-6)
        v0, g0 = vg(w_small, small, 1e-6)
    assert float(v0) > 0.0
    np.testing.assert_allclose(float(v), float(v0), rtol=1e-9)
    np.testing.assert_array_equal(np.asarray(g)[top], 0.0)
    np.testing.assert_allclose(np.asarray(g)[kept], np.asarray(g0)[: len(kept)], rtol=1e-6, atol=1e-9)


def test_config_diff_defaults_missing_keys_and_ignores_stability_keys_at_lam_0(tmp_path):
    cfg = _cfg(tmp_path, lam=0.0)
    old = {k: v for k, v in cfg.items() if k != "absent_below"}  # a run from before the key existed
    assert T.config_diff(old, cfg) == []
    assert T.config_diff(old, dict(cfg, lam=1.0, absent_below=1e-6)) == ["absent_below", "lam"]
    assert T.config_diff(old, dict(cfg, absent_below=1e-6)) == []  # lam 0: no stability term
    assert T.config_diff(dict(old, lam=1.0), dict(cfg, lam=1.0, absent_below=1e-6)) == ["absent_below"]
    assert T.config_diff(old, dict(cfg, bin_weight=cfg["bin_weight"] + 1)) == ["bin_weight"]
    with pytest.raises(T.ConfigError, match="absent_below"):
        _cfg(tmp_path, absent_below=1.0)
    with pytest.raises(T.ConfigError, match="solver_iters"):
        _cfg(tmp_path, solver_iters=0)
    assert T.loss_options(_cfg(tmp_path, solver_iters=100)).iters == 100
    from stablelego_jax.loss import LossOptions

    assert T.loss_options(cfg).iters == LossOptions().iters == 30


def test_crop_equals_full_grid():
    s = procedural_shape(3, kind="bridge")
    params = net.init_params(jax.random.PRNGKey(1), 8)
    full = np.asarray(net.apply(params, net.features(s.vox)[None]))[0]
    c, o = net.crop(s.vox, (10, 10, 6))
    part = np.asarray(net.apply(params, net.features(c)[None]))[0]
    xs, ys, zs = np.nonzero(c)
    np.testing.assert_allclose(part[xs, ys, zs], full[xs + o[0], ys + o[1], zs], atol=1e-5)
    assert np.abs(part[xs, ys, zs]).max() > 0


def test_decoding_never_overlaps_and_stays_inside():
    rng = np.random.default_rng(0)
    for seed in range(6):
        c, _ = net.crop(procedural_shape(seed).vox, (10, 10, 6))
        valid = net.valid_placements(c)
        p = np.where(valid, rng.random(valid.shape), 0.0)
        for thr in (0.05, 0.5, 0.95):
            idx, pos, size = net.decode(p, thr)
            count = np.zeros(c.shape, int)
            for (x, y, z), (sx, sy) in zip(pos.tolist(), size.tolist()):
                count[x:x + sx, y:y + sy, z] += 1
            assert count.max() <= 1 and not (count.astype(bool) & ~c).any()
            assert (p[tuple(idx.T)] >= thr).all()
            iou = net.decoded_iou(c, pos, size)
            assert np.isclose(iou, count.sum() / c.sum())
        # filling with the valid placements covers the shape exactly even when
        # (as for a saturated network) most probabilities underflow to 0
        q = np.where(rng.random(valid.shape) < 0.02, p, 0.0)
        _, pos, size = net.decode(q, 0.5, fill=True, valid=valid)
        assert net.decoded_iou(c, pos, size) == 1.0
        # the soft coverage of a 0/1 decoding is its cell count
        q = np.zeros_like(p)
        q[tuple(idx.T)] = 1.0
        np.testing.assert_allclose(np.asarray(net.coverage(jnp.asarray(q[None])))[0], count)


def test_size_prior_orders_by_probability_times_area():
    """decode(size_prior=beta) takes placements in the order prob x area^beta:
    a 2x2 of probability 0.1 goes before the 1x1s of 0.5 when 0.1 x 4^beta
    > 0.5; beta 0 is the plain order; the candidates never change."""
    c = np.zeros((2, 2, 1), bool)
    c[:] = True
    valid = net.valid_placements(c)
    k22 = net.TYPES.index((2, 2))
    p = np.zeros(valid.shape)
    p[:, :, 0, net.TYPES.index((1, 1))] = 0.5
    p[0, 0, 0, k22] = 0.1
    plain = net.decode(p, 0.05, fill=True, valid=valid)
    np.testing.assert_array_equal(plain[0], net.decode(p, 0.05, True, valid, size_prior=0.0)[0])
    assert len(plain[0]) == 4 and (plain[2] == 1).all()
    for beta, n in ((1.0, 4), (2.0, 1)):  # 0.1 x 4 < 0.5 < 0.1 x 16
        idx, _, size = net.decode(p, 0.05, fill=True, valid=valid, size_prior=beta)
        assert len(idx) == n and net.decoded_iou(c, idx[:, :3], size) == 1.0
    # the strict decoding keeps its threshold: the 2x2 is below 0.2, whatever beta
    assert len(net.decode(p, 0.2, size_prior=2.0)[0]) == 4
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="size_prior"):
            net.decode(p, 0.5, size_prior=bad)


def test_coverage_sums_every_placement_window_and_its_gradient():
    # a direct count: each placement adds its probability to the cells of its
    # window, clipped to the grid
    rng = np.random.default_rng(3)
    p = rng.random((2, 9, 11, 3, len(net.TYPES)))
    want = np.zeros(p.shape[:4])
    for b, x, y, z, k in np.ndindex(*p.shape):
        sx, sy = net.TYPES[k]
        want[b, x:x + sx, y:y + sy, z] += p[b, x, y, z, k]
    np.testing.assert_allclose(np.asarray(net.coverage(jnp.asarray(p))), want, rtol=1e-12)
    # d sum(cov * u) / d p[placement] = the sum of u over its window
    u = rng.random(p.shape[:4])
    g = np.asarray(jax.grad(lambda q: (net.coverage(q) * u).sum())(jnp.asarray(p)))
    for b, x, y, z, k in [(0, 0, 0, 0, 0), (1, 8, 10, 2, 13), (0, 3, 4, 1, 10), (1, 5, 2, 0, 7)]:
        sx, sy = net.TYPES[k]
        assert np.isclose(g[b, x, y, z, k], u[b, x:x + sx, y:y + sy, z].sum(), rtol=1e-12)


def test_checkpoint_resume_continues_exactly_and_replay_draws_its_next_batch(tmp_path, monkeypatch):
    """A resumed run ends where an uninterrupted one does; replay() of the
    checkpoint draws the batch the resumed run draws next, and
    batch_weights gives its subsets' shares of the probabilities."""
    cfg = _cfg(tmp_path)
    p_full, h_full = T.train(cfg, str(tmp_path / "a"), log=open(os.devnull, "w"))
    T.train(cfg, str(tmp_path / "b"), log=open(os.devnull, "w"), max_steps=2)
    z = np.load(tmp_path / "b" / "checkpoint.npz")
    assert int(z["step"]) == 2 and "param_0" in z.files and "opt_0" in z.files
    run = T.replay(str(tmp_path / "b" / "checkpoint.npz"))
    assert run.step == 2 and T.config_diff(run.cfg, cfg) == []
    probs_fn = T.make_fns(run.cfg)[0]
    x, valid, _, p, sub = T.draw_batch(run.arrays, run.cfg, run.rng, run.params, probs_fn)
    assert cfg["share_scope"] == "all"  # shares of every placement covering a cell, then the subset's
    w = T.batch_weights(run.cfg, run.params, x, valid, sub)
    wts = np.asarray(net.existence_weights(p, net.coverage(p), cfg["share_floor"]))
    expected = np.take_along_axis(wts.reshape(len(p), -1), sub.fi, axis=1) * sub.mask
    assert w.shape == sub.fi.shape and (w[sub.mask == 0] == 0).all() and w.max() > 0
    np.testing.assert_allclose(w, expected, rtol=1e-12, atol=1e-300)
    # "subset": shares among the subset's own placements
    w = T.batch_weights(dict(run.cfg, share_scope="subset"), run.params, x, valid, sub)
    ps = np.take_along_axis(p.reshape(len(p), -1), sub.fi, axis=1) * sub.mask
    expected = np.asarray(net.subset_shares(ps, sub.inc, cfg["share_floor"], cfg["share_power"]))
    np.testing.assert_allclose(w, expected, rtol=1e-12, atol=1e-300)
    drawn = []
    draw = T.draw_batch

    def recording(*args, **kw):
        out = draw(*args, **kw)
        drawn.append(out)
        return out

    monkeypatch.setattr(T, "draw_batch", recording)
    p_res, h_res = T.train(cfg, str(tmp_path / "b"), resume=True, log=open(os.devnull, "w"))
    np.testing.assert_array_equal(drawn[0][0], x)
    np.testing.assert_array_equal(drawn[0][4].fi, sub.fi)
    for (w1, b1), (w2, b2) in zip(p_full, p_res):
        np.testing.assert_array_equal(np.asarray(w1), np.asarray(w2))
        np.testing.assert_array_equal(np.asarray(b1), np.asarray(b2))
    assert [h["loss"] for h in h_full if "loss" in h] == [h["loss"] for h in h_res if "loss" in h]


def test_evaluate_scores_each_decoding_and_refines_the_filled_one(tmp_path, capsys):
    """``stablelego evaluate --heuristic --refine S``: a row per held-out shape
    and method; the refined rows are exact covers (IoU 1) whose verdict is the
    exact solver's, at least as stable as the filled decoding they start from."""
    cfg = _cfg(tmp_path, lam=0.0, steps=2, n_procedural=10)
    T.train(cfg, str(tmp_path / "run"), log=open(os.devnull, "w"))
    ckpt, out = str(tmp_path / "run" / "checkpoint.npz"), str(tmp_path / "held.jsonl")
    assert main(["evaluate", "--checkpoint", ckpt, "--out", out, "--heuristic", "--refine", "20"]) == 0
    rows = [json.loads(line) for line in open(out)]
    shapes = sorted({r["shape"] for r in rows})
    assert shapes
    by = {(r["shape"], r["method"]): r for r in rows}
    for name in shapes:
        ref, filled = by[(name, "generator_refined")], by[(name, "generator_filled")]
        assert ref["iou"] == 1.0 == filled["iou"] and "error" not in ref
        assert ref["stable"] >= filled["stable"] and ref["started_stable"] == filled["stable"]
        assert (name, "heuristic") in by and (name, "generator") in by
    err = capsys.readouterr().err
    assert err.count("generator_refined [") == len(shapes) == err.count("heuristic_refined [")
    assert all(by[(n, "heuristic_refined")]["stable"] >= by[(n, "heuristic")]["stable"] for n in shapes)
    # --size-prior: the generator's rows carry beta (the heuristic's do not); filled covers stay exact
    out2 = str(tmp_path / "prior.jsonl")
    assert main(["evaluate", "--checkpoint", ckpt, "--out", out2, "--size-prior", "4", "--heuristic"]) == 0
    rows2 = [json.loads(line) for line in open(out2)]
    assert {r["method"] for r in rows2} == {"generator", "generator_filled", "heuristic"}
    assert all(r.get("size_prior") == (None if r["method"] == "heuristic" else 4.0) for r in rows2)
    assert all(r["iou"] == 1.0 for r in rows2 if r["method"] == "generator_filled")
    # --split fresh: N new objects of the config's recipe, none of them held out
    out3 = str(tmp_path / "fresh.jsonl")
    assert main(["evaluate", "--checkpoint", ckpt, "--out", out3, "--split", "fresh", "--fresh", "3"]) == 0
    fresh = {r["shape"] for r in map(json.loads, open(out3))}
    assert len(fresh) == 3 and not fresh & set(shapes)
    # --fresh with another split: an error, nothing written
    assert main(["evaluate", "--checkpoint", ckpt, "--out", str(tmp_path / "x.jsonl"), "--fresh", "3"]) == 2
    assert not (tmp_path / "x.jsonl").exists() and "--split fresh" in capsys.readouterr().err
    for bad in ("-1", "nan"):
        with pytest.raises(SystemExit) as exc:
            main(["evaluate", "--checkpoint", ckpt, "--out", str(tmp_path / "x.jsonl"), "--size-prior", bad])
        assert exc.value.code == 2 and not (tmp_path / "x.jsonl").exists()
    # a refinement budget that is not a positive number of seconds: a usage error, nothing written
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--checkpoint", ckpt, "--out", str(tmp_path / "x.jsonl"), "--refine", "0"])
    assert exc.value.code == 2 and not (tmp_path / "x.jsonl").exists()


def test_evaluate_writes_the_layouts_it_scored(tmp_path, capsys):
    """``evaluate --layouts DIR``: each row's layout as StableLego JSON in
    DIR/METHOD/SHAPE.json, named in the row; read back, it covers the shape's
    cells (the exact covers exactly) and gets the row's verdict; a DIR that
    cannot be a folder is refused before anything is evaluated or written."""
    from stablelego_jax.analysis import analyze_layout
    from stablelego_jax.formats.reader import load_layout
    from stablelego_jax.layout import cells_of

    cfg = _cfg(tmp_path, lam=0.0, steps=2, n_procedural=10)
    T.train(cfg, str(tmp_path / "run"), log=open(os.devnull, "w"))
    ckpt, out, lay_dir = str(tmp_path / "run" / "checkpoint.npz"), str(tmp_path / "held.jsonl"), tmp_path / "lay"
    assert main(["evaluate", "--checkpoint", ckpt, "--out", out, "--heuristic", "--refine-solves", "3",
                 "--layouts", str(lay_dir)]) == 0
    rows = [json.loads(line) for line in open(out)]
    vox = {s.name: s.vox for s in T.split_shapes(T.load_checkpoint(ckpt)[4], "heldout")}
    methods = {"generator", "generator_filled", "generator_refined", "heuristic", "heuristic_refined"}
    assert {r["method"] for r in rows} == methods
    written = 0
    for r in rows:
        if r["n_bricks"] == 0:  # an empty decoding: no file
            assert "layout" not in r
            continue
        assert r["layout"] == str(lay_dir / r["method"] / (r["shape"] + ".json"))
        lay = load_layout(r["layout"])
        assert lay.n == r["n_bricks"]
        cells, _ = cells_of(lay.pos, lay.size)
        assert vox[r["shape"]][tuple(cells.T)].all()  # inside the shape, in its voxel grid
        if r["iou"] == 1.0:
            assert len(cells) == int(vox[r["shape"]].sum())
        if r["method"] in ("heuristic", "generator_refined"):
            assert analyze_layout(lay, solver="exact").stable == r["stable"]
        written += 1
    assert written == sum(1 for _ in lay_dir.rglob("*.json")) >= 2 * len(vox)
    # a file where the folder should be: refused at once, nothing written
    (tmp_path / "f").write_text("x")
    bad_out = tmp_path / "bad.jsonl"
    capsys.readouterr()
    assert main(["evaluate", "--checkpoint", ckpt, "--out", str(bad_out), "--layouts", str(tmp_path / "f")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and str(tmp_path / "f") in err[0]
    assert not bad_out.exists() and (tmp_path / "f").read_text() == "x"
    # results that cannot be written (in a folder under a file; a folder): refused at once too
    for bad in (tmp_path / "f" / "held.jsonl", lay_dir):
        assert main(["evaluate", "--checkpoint", ckpt, "--out", str(bad)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"error: {bad}: cannot write")
    assert (tmp_path / "f").read_text() == "x"


def test_write_results_leaves_no_folder_when_it_fails(tmp_path):
    """``write_results``: when any file cannot be written, nothing is, not
    even the layout folders it made for them."""
    from stablelego_jax.layout import LayoutError, brick_layout
    from stablelego_jax.train.evaluate import write_results

    lay = brick_layout(np.zeros((1, 3), int), np.ones((1, 2), int))
    rows = [{"method": "heuristic", "shape": "s"}]
    (tmp_path / "res").mkdir()  # the results path is a folder
    with pytest.raises(LayoutError):
        write_results(str(tmp_path / "res"), rows, str(tmp_path / "lay" / "deep"), {("heuristic", "s"): lay})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res"] and not any((tmp_path / "res").iterdir())
    # and when they can: the rows and the layout, in the folders it made
    write_results(str(tmp_path / "out" / "r.jsonl"), rows, str(tmp_path / "lay" / "deep"), {("heuristic", "s"): lay})
    assert json.loads((tmp_path / "out" / "r.jsonl").read_text())["layout"] == str(
        tmp_path / "lay" / "deep" / "heuristic" / "s.json")
    assert (tmp_path / "lay" / "deep" / "heuristic" / "s.json").is_file()


def test_refinement_in_exact_solves_gives_the_same_rows_twice():
    """``evaluate --refine-solves N``: each start refined within N exact
    solves and no clock, so two runs give the same rows, marked with the
    budget: a start that needs more solves falls, one that needs fewer stands."""
    import types

    from stablelego_jax.generate.voxels import random_voxel_shape
    from stablelego_jax.layout import brick_layout
    from stablelego_jax.train.evaluate import refined_rows

    shapes = [types.SimpleNamespace(name=f"boxes{k}", kind="boxes", vox=random_voxel_shape(k, grid=8, kind="boxes"))
              for k in (0, 1)]
    ones = [brick_layout(np.argwhere(s.vox), np.ones((int(s.vox.sum()), 2), int)) for s in shapes]
    a, b = (refined_rows("generator_refined", shapes, ones, None, None, {"seed": 0}, solves=4) for _ in range(2))

    def no_clock(rows):
        return [{k: v for k, v in r.items() if k != "refine_s"} for r in rows]

    assert no_clock(a) == no_clock(b)
    assert all(r["budget_solves"] == 4 and r["seed"] == 0 and 1 <= r["exact_calls"] <= 6 for r in a)
    # boxes 1 stands within 3 solves from its unit cover, boxes 0 needs more than 4
    assert [r["stable"] for r in a] == [False, True]
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "--checkpoint", "x.npz", "--out", "x.jsonl", "--refine-solves", "0"])
    assert exc.value.code == 2


def test_bad_config_names_the_file(tmp_path, capsys):
    missing = str(tmp_path / "nope.json")
    assert main(["train", "--config", missing, "--out", str(tmp_path / "o")]) == 2
    assert "nope.json" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"stepz": 3}))
    with pytest.raises(T.ConfigError, match="bad.json.*unknown config key 'stepz'"):
        T.load_config(str(bad))
    bad.write_text(json.dumps({"steps": "many"}))
    with pytest.raises(T.ConfigError, match="'steps' must be int"):
        T.load_config(str(bad))
    bad.write_text("{not json")
    assert main(["train", "--config", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "bad.json" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_subset_shares_keep_every_cell_whole():
    # placements 0: 1x1 on cell a; 1: 1x2 on cells a, b; 2: 1x1 on cell b; 3: 1x1 alone on cell c; 4: padding
    inc = np.zeros((1, 4, 5))
    inc[0, 0, [0, 1]] = 1  # cell a
    inc[0, 1, [1, 2]] = 1  # cell b
    inc[0, 2, 3] = 1  # cell c
    ps = jnp.asarray([[0.6, 0.2, 0.9, 0.01, 0.0]])
    w = np.asarray(net.subset_shares(ps, jnp.asarray(inc)))[0]
    # a lone placement exists fully whatever its probability; padding not at all
    assert np.isclose(w[3], 1.0) and w[4] == 0.0
    # overlapping alternatives split their cells in the ratio of their probabilities
    np.testing.assert_allclose(w[:3], [0.6 / 0.8, 0.2 / 1.1, 0.9 / 1.1])
    # so no cell of the subset ends up with less than its most contested share
    cell_mass = inc[0] @ w
    assert (cell_mass[:3] >= 0.9).all()
    # lowering a lone placement's probability does not lower its weight
    g = jax.grad(lambda q: net.subset_shares(q, jnp.asarray(inc))[0, 3])(ps)
    assert float(g[0, 3]) == 0.0


def test_tempered_shares_reach_a_losing_alternative():
    # placement 0: 1x1 on cell a at p ~ 1; placement 1: a 1x2 alternative on cells a, b
    # at p = 1e-4; placement 2: 1x1 on cell b at p ~ 1
    inc = np.zeros((1, 2, 3))
    inc[0, 0, [0, 1]] = 1
    inc[0, 1, [1, 2]] = 1
    ps = jnp.asarray([[0.999, 1e-4, 0.999]])
    grads = {}
    for power in (1.0, 0.25):
        w = np.asarray(net.subset_shares(ps, jnp.asarray(inc), power=power))[0]
        # the cells keep their full mass either way
        np.testing.assert_allclose(inc[0] @ w, 1.0)
        g = jax.grad(lambda a: net.subset_shares(jax.nn.sigmoid(a), jnp.asarray(inc), power=power)[0, 1])(
            jnp.log(ps / (1 - ps)))
        grads[power] = float(g[0, 1])  # d share / d logit of the alternative
    # tempered: the alternative holds (1e-4)^0.25 / (0.999^0.25 + ...) ~ 0.09 of its cells
    w = np.asarray(net.subset_shares(ps, jnp.asarray(inc), power=0.25))[0]
    assert 0.05 < w[1] < 0.15
    assert grads[1.0] < 2e-4 and grads[0.25] > 100 * grads[1.0]


def test_grad_floor_moves_saturated_placements(tmp_path):
    # with the network's output bias far negative every probability is ~0, so
    # d p / d logit ~ 0: without the floor the stability term cannot move anything
    arr = _batch(_cfg(tmp_path))
    out = {}
    for floor in (0.0, 0.1):
        cfg = _cfg(tmp_path, grad_floor=floor, out_bias=-40.0)
        probs_fn, _, _, _, grad_fn = T.make_fns(cfg)
        params = T.initial_params(cfg, 0)
        with one_blas_thread():
            p = np.asarray(probs_fn(params, arr.x, arr.valid))
            sub = T.batch_subsets(p, arr.valid, cfg, np.random.default_rng(0), arr.span)
            _, aux, g1 = grad_fn(params, np.float64(100.0), np.float64(0.0), arr.x, arr.valid, arr.target, *sub)
            _, _, g0 = grad_fn(params, np.float64(0.0), np.float64(0.0), arr.x, arr.valid, arr.target, *sub)
        assert float(aux[2]) > 0.0  # the filled subset puts every cell in the problem
        out[floor] = float(jnp.abs(g1[-1][1] - g0[-1][1]).sum())  # stability gradient on the output bias
    assert out[0.0] < 1e-9 < out[0.1]


def test_config_rejects_unknown_choices(tmp_path):
    for key, val in (("subset_base", "partial"), ("share_scope", "cells"), ("lr_schedule", "linear"),
                     ("random_pool", "all")):
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps({key: val}))
        with pytest.raises(T.ConfigError, match=f"bad.json.*'{key}' must be one of"):
            T.load_config(str(bad))


def test_share_power_must_be_in_range(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"share_power": 0.0}))
    with pytest.raises(T.ConfigError, match="bad.json.*share_power"):
        T.load_config(str(bad))


def test_random_pool_valid_draws_beyond_the_spanning_placements(tmp_path):
    # a solid box has no overhang, so no spanning placements: with the default
    # pool the random competitors are none, with "valid" they are drawn from
    # every valid placement (e.g. a 2x1 that could replace two 1x1 in a column)
    box = procedural_shape(0, kind="box")
    sizes = {}
    for pool in ("span", "valid"):
        cfg = _cfg(tmp_path, random_pool=pool, competitors=0, random_competitors=6, subset_base="filled")
        arr = T.Arrays([box], cfg["crop"], cfg["grid"])
        assert not arr.span.any()
        p = np.where(arr.valid[0], 0.2, 0.0)
        sub = T.select_subset(p, arr.valid[0], cfg, np.random.default_rng(0), arr.span[0])
        dec = len(net.decode(p, cfg["threshold"], True, arr.valid[0])[0])
        sizes[pool] = int(sub.mask.sum()) - dec
        assert arr.valid[0].ravel()[sub.fi[sub.mask]].all()
    assert sizes == {"span": 0, "valid": 6}


def test_brick_weight_charges_each_placement(tmp_path):
    # a 2x4x1 slab tiled exactly (fidelity error 0) once by eight 1x1 bricks
    # and once by one 2x4: with brick_weight the fidelity term is
    # brick_weight * (number of bricks), so the 2x4 tiling is cheaper
    vox = np.zeros((10, 10, 6), bool)
    vox[:2, :4, 0] = True
    valid = net.valid_placements(vox)[None]
    k11, k24 = net.TYPES.index((1, 1)), net.TYPES.index((2, 4))
    # a network with no hidden layer: logit = 120 * (input channel c of the
    # type) - 60, so p = 1 where that channel is 1 and ~1e-26 elsewhere
    w = np.zeros((1, 1, 1, net.N_FEATURES, len(net.TYPES)), np.float32)
    w[0, 0, 0, 0, k11] = w[0, 0, 0, 1, k24] = 120.0
    params = [(jnp.asarray(w), jnp.full((len(net.TYPES),), -60.0, jnp.float32))]
    x_ones = np.zeros((1, 10, 10, 6, net.N_FEATURES), np.float32)
    x_ones[0, ..., 0] = vox  # a 1x1 on every cell of the slab
    x_big = np.zeros_like(x_ones)
    x_big[0, 0, 0, 0, 1] = 1.0  # one 2x4 at the corner
    fid = {}
    for bw in (0.0, 0.3):
        cfg = _cfg(tmp_path, brick_weight=bw, dilations=[])
        probs_fn, _, _, terms, _ = T.make_fns(cfg)
        for name, x in (("ones", x_ones), ("big", x_big)):
            p = np.asarray(probs_fn(params, x, valid))
            assert p.sum() == pytest.approx(8 if name == "ones" else 1, rel=1e-9)
            sub = T.batch_subsets(p, valid, cfg, np.random.default_rng(0))
            fid[bw, name] = float(terms(params, x, valid, vox[None], *sub)[0])
    assert fid[0.0, "ones"] < 1e-9 and fid[0.0, "big"] < 1e-9
    assert fid[0.3, "ones"] == pytest.approx(0.3 * 8, rel=1e-6)
    assert fid[0.3, "big"] == pytest.approx(0.3 * 1, rel=1e-6)


def test_config_diff_names_the_changed_keys(tmp_path):
    # train --resume and benchmarks/training.py's reuse check both rely on it
    a = _cfg(tmp_path)
    b = dict(a, lr=0.02, steps=a["steps"] + 10, brick_weight=0.1)
    assert T.config_diff(a, a) == []
    assert T.config_diff(a, b) == ["brick_weight", "lr", "steps"]
    assert T.config_diff(a, b, ignore=("steps",)) == ["brick_weight", "lr"]


def test_training_without_optax_is_a_clear_error_and_writes_nothing(tmp_path):
    """optax is the optional 'train' extra: without it, one line, exit 2, no folder."""
    import subprocess
    import sys

    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"mesh_dir": None, "steps": 1}))
    out = tmp_path / "o"
    code = ("import sys; sys.modules['optax'] = None\n"
            "from stablelego_jax.cli import main\n"
            f"sys.exit(main(['train', '--config', {str(cfg)!r}, '--out', {str(out)!r}]))")
    root = os.path.join(os.path.dirname(__file__), "..")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                       env=dict(os.environ, PYTHONPATH=root))
    assert r.returncode == 2 and "optax" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()


def test_training_on_a_pool_that_would_hang_is_a_clear_error(tmp_path, capsys, monkeypatch):
    """Training with ``stability_solves`` "batch" solves its batch under vmap:
    on a jaxlib whose batched LAPACK calls deadlock a larger XLA pool
    (stablelego_jax.blas), a pool of 2 is a one-line error (exit 2) and
    nothing is written."""
    from stablelego_jax.blas import lapack_pool_deadlock

    if not lapack_pool_deadlock():
        pytest.skip("this jaxlib's batched LAPACK calls do not deadlock a pool")
    monkeypatch.setenv("PJRT_NPROC", "2")  # what a process with a 2-thread pool would have
    cfg = tmp_path / "batch.json"
    cfg.write_text(json.dumps({"stability_solves": "batch"}))
    assert main(["train", "--config", str(cfg), "--steps", "1", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "deadlock" in err and "PJRT_NPROC" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_layered_subsets_give_the_dense_loss_and_gradient(tmp_path):
    # the same placements solved by the block-tridiagonal factorisation
    # (layers x slots) instead of one dense block: the same stability term
    # and gradient (one interior point, two factorisations); the config's
    # fixed padding, solved as one batch
    dense = _cfg(tmp_path, stability_solves="batch")
    layered = _cfg(tmp_path, stability_solves="batch", layers=6, slots=8, chunk_pad=64)
    arr = _batch(dense)
    params = T.initial_params(dense, 0)
    out = {}
    with one_blas_thread():
        for name, cfg in (("dense", dense), ("layered", layered)):
            probs_fn, _, _, _, grad_fn = T.make_fns(cfg)
            p = np.asarray(probs_fn(params, arr.x, arr.valid))
            sub = T.batch_subsets(p, arr.valid, cfg, np.random.default_rng(0))
            assert (sub.prob.layers is None) == (name == "dense")
            out[name] = (sub.fi, grad_fn(params, np.float64(cfg["lam"]), np.float64(0.1),
                                         arr.x, arr.valid, arr.target, *sub))
    np.testing.assert_array_equal(out["dense"][0], out["layered"][0])  # the same placements
    (ld, auxd, gd), (ll, auxl, gl) = out["dense"][1], out["layered"][1]
    assert float(auxd[2]) > 1e-4  # a stability term to compare
    assert float(ll) == pytest.approx(float(ld), rel=1e-8)
    assert float(auxl[2]) == pytest.approx(float(auxd[2]), rel=1e-8)
    for (wd, bd), (wl, bl) in zip(gd, gl):
        scale = max(float(jnp.abs(wd).max()), 1e-12)
        assert float(jnp.abs(wl - wd).max()) <= 1e-6 * scale
        assert float(jnp.abs(bl - bd).max()) <= 1e-6 * max(float(jnp.abs(bd).max()), 1e-12)


def test_layered_config_needs_a_layer_for_every_crop_layer(tmp_path):
    with pytest.raises(T.ConfigError, match="layers"):
        _cfg(tmp_path, layers=3)  # the crop is 6 high
    with pytest.raises(T.ConfigError, match="chunk_pad"):
        _cfg(tmp_path, layers=6, chunk_pad=0)
