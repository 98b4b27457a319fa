"""The layer-by-layer generator (stablelego_jax.train.layers) and its training (config net "layers", imitate)."""
import json
import os
import re

import jax
import numpy as np
import pytest

from stablelego_jax.blas import one_blas_thread
from stablelego_jax.cli import main
from stablelego_jax.generate.voxels import merge_voxels
from stablelego_jax.train import layers, net
from stablelego_jax.train import train as T
from stablelego_jax.train.shapes import procedural_shape

pytestmark = pytest.mark.usefixtures("x64")

TINY = {"n_procedural": 8, "mesh_dir": None, "steps": 3, "batch": 2, "checkpoint_every": 2, "eval_every": 100,
        "eval_train": 2, "eval_heldout": False, "log_every": 1, "width": 8, "dilations": [1, 2, 1], "lam": 0.0,
        "lr": 0.01, "net": "layers", "imitate": 1.0, "n_pad": 16, "m_pad": 512, "p_pad": 32, "competitors": 4,
        "random_competitors": 2}


def _cfg(tmp_path, **kw):
    path = tmp_path / "cfg.json"
    path.write_text(json.dumps(dict(TINY, **kw)))
    return T.load_config(str(path))


def test_features_read_the_shape_and_the_joints_of_the_layer_below():
    vox = np.zeros((6, 4, 3), bool)
    vox[:, :2, 0] = True  # a 6 x 2 slab
    vox[1:5, :2, 1] = True  # a 4 x 2 slab on it
    ids = -np.ones(vox.shape, np.int32)
    ids[0:2, :2, 0], ids[2:6, :2, 0] = 0, 1  # a joint between x = 1 and x = 2
    f = layers.features(vox, ids, grid=20)
    assert f.shape == (6, 4, 3, layers.N_FEATURES)
    np.testing.assert_array_equal(f[..., layers.OCCUPIED], vox)
    np.testing.assert_array_equal(f[:, :, 0, 1], vox[:, :, 1] * 0)  # layer z - 1 of layer 0: nothing
    np.testing.assert_array_equal(f[:, :, 0, 3], vox[:, :, 1])  # layer z + 1
    assert (f[:, :, 0, 10] == 0).all()  # no layer below layer 0
    jx = f[:, :, 1, 10]
    assert jx[1, 0] == jx[1, 1] == 1 and jx.sum() == 2  # the joint below layer 1, along x
    assert (f[:, :, 1, 11] == 0).all()  # none along y
    held = f[:, :, 1, 6]
    np.testing.assert_array_equal(held, vox[:, :, 1])  # every cell of layer 1 rests on layer 0
    np.testing.assert_allclose(f[:, :, 1, 9], vox[:, :, 1] * 2 / 20, rtol=1e-6)  # height (z + 1) / grid
    # one layer alone is that layer of the whole; a layer reads only the bricks below it
    np.testing.assert_array_equal(layers.features(vox, ids, 20, z=1), f[:, :, 1:2])
    ids2 = ids.copy()
    ids2[:, :, 1] = 7
    np.testing.assert_array_equal(layers.features(vox, ids2, 20)[:, :, :2], f[:, :, :2])


def test_distance_to_held_cells_marks_the_overhang():
    vox = np.zeros((8, 1, 2), bool)
    vox[0:2, 0, 0] = True
    vox[0:6, 0, 1] = True  # cells 2..5 of layer 1 overhang
    f = layers.features(vox, -np.ones(vox.shape, np.int32))
    np.testing.assert_allclose(f[:6, 0, 1, 12], [0, 0, 1 / 8, 2 / 8, 3 / 8, 4 / 8])


def test_teacher_is_the_merge_cover():
    s = procedural_shape(2, kind="table")
    ids, place = layers.teacher(s.vox)
    lay = merge_voxels(s.vox)
    assert place.sum() == lay.n
    np.testing.assert_array_equal(ids >= 0, s.vox)
    assert (place <= net.valid_placements(s.vox)).all()  # every teacher placement lies inside the shape
    assert len(np.unique(ids[ids >= 0])) == lay.n


def test_each_layer_is_its_own_and_a_crop_equals_the_grid():
    s = procedural_shape(3, kind="bridge")
    ids, _ = layers.teacher(s.vox)
    params = layers.init_params(jax.random.PRNGKey(0), 8, (1, 2, 1))
    x = layers.features(s.vox, ids)[None]
    out = np.asarray(layers.apply(params, x, (1, 2, 1)))[0]
    z = int(np.nonzero(s.vox.any((0, 1)))[0].max())
    x2 = x.copy()
    x2[0, :, :, z, 5] += 1.0  # change one layer's input
    out2 = np.asarray(layers.apply(params, x2, (1, 2, 1)))[0]
    assert not np.allclose(out2[:, :, z], out[:, :, z])
    np.testing.assert_array_equal(out2[:, :, :z], out[:, :, :z])
    c, o = net.crop(s.vox, (12, 12, s.vox.shape[2]))
    sub = ids[o[0]:o[0] + 12, o[1]:o[1] + 12]
    ids_c = -np.ones(c.shape, np.int32)
    ids_c[:sub.shape[0], :sub.shape[1]] = sub
    part = np.asarray(layers.apply(params, layers.features(c, ids_c)[None], (1, 2, 1)))[0]
    xs, ys, zs = np.nonzero(c)
    np.testing.assert_allclose(part[xs, ys, zs], out[xs + o[0], ys + o[1], zs], atol=1e-5)


def test_decoding_bottom_up_covers_each_shape_exactly():
    shapes = [procedural_shape(i, kind=k) for i, k in enumerate(("cantilever", "stairs", "mushroom"))]
    vox = np.stack([net.crop(s.vox, (12, 12, 8))[0] for s in shapes])
    valid = np.stack([net.valid_placements(v) for v in vox])
    params = layers.init_params(jax.random.PRNGKey(1), 8, (1, 2, 1))
    seen = []

    def probs_fn(p, x, v):
        seen.append(x.shape)
        return np.asarray(layers.probabilities(p, x, v, (1, 2, 1)))

    for fill in (True, False):
        for v, (pos, size) in zip(vox, layers.decode(probs_fn, params, vox, valid, fill=fill)):
            occ = np.zeros(v.shape, int)
            for (x, y, z), (sx, sy) in zip(pos, size):
                occ[x:x + sx, y:y + sy, z] += 1
            assert occ.max() <= 1 and not (occ.astype(bool) & ~v).any()
            if fill:
                np.testing.assert_array_equal(occ.astype(bool), v)
            assert (np.diff(pos[:, 2]) >= 0).all()  # lowest layers first
    assert all(s[3] == 1 for s in seen)  # one layer a call, the batch's shapes together
    assert max(s[0] for s in seen) == 3


def test_training_imitates_the_teacher_and_evaluates_bottom_up(tmp_path, capsys):
    """A few steps on one batch raise the teacher's placements' probabilities;
    ``stablelego train`` / ``evaluate`` run the layers net end to end and
    a checkpoint reloads to the same parameters."""
    cfg = _cfg(tmp_path)
    probs_fn, step_fn, opt, terms, _ = T.make_fns(cfg)
    shapes = [procedural_shape(i, kind=k) for i, k in enumerate(("cantilever", "tee"))]
    arr = T.shape_arrays(shapes, cfg)
    assert arr.x.shape[-1] == layers.N_FEATURES and arr.teacher.shape == arr.valid.shape
    params = T.initial_params(cfg, 0)
    goal = arr.goal(np.arange(2))
    assert isinstance(goal, tuple) and goal[1] is not None
    with one_blas_thread():
        before = np.asarray(probs_fn(params, arr.x, arr.valid))[arr.teacher].mean()
        fid0 = float(terms(params, arr.x, arr.valid, goal, None, None, None, None)[0])
        fid_plain = float(T.make_fns(dict(cfg, imitate=0.0))[3](params, arr.x, arr.valid, arr.target, None, None,
                                                                  None, None)[0])
        assert fid0 > fid_plain  # the cross-entropy adds to the fidelity
        opt_state = opt.init(params)
        for _ in range(15):
            params, opt_state, _, _ = step_fn(params, opt_state, np.float64(0.0), np.float64(0.1), arr.x,
                                              arr.valid, goal, T.Subset(None, None, None, None))
        after = np.asarray(probs_fn(params, arr.x, arr.valid))[arr.teacher].mean()
    assert after > before + 0.1
    run = str(tmp_path / "run")
    assert main(["train", "--config", str(tmp_path / "cfg.json"), "--out", run]) == 0
    ckpt = os.path.join(run, "checkpoint.npz")
    p1 = T.load_checkpoint(ckpt)[0]
    assert p1[0][0].shape == (3, 3, layers.N_FEATURES, 8)
    out = str(tmp_path / "val.jsonl")
    assert main(["evaluate", "--checkpoint", ckpt, "--out", out, "--heuristic"]) == 0
    rows = [json.loads(line) for line in open(out)]
    assert {r["method"] for r in rows} == {"generator", "generator_filled", "heuristic"}
    assert all(r["iou"] == 1.0 for r in rows if r["method"] == "generator_filled")


def test_stability_term_reaches_the_layers_net(tmp_path):
    cfg = _cfg(tmp_path, lam=50.0)
    probs_fn, _, _, _, grad_fn = T.make_fns(cfg)
    shapes = [procedural_shape(i, kind=k) for i, k in enumerate(("cantilever", "tee"))]
    arr = T.shape_arrays(shapes, cfg)
    params = T.initial_params(cfg, 0)
    with one_blas_thread():
        p = np.asarray(probs_fn(params, arr.x, arr.valid))
        sub = T.batch_subsets(p, arr.valid, cfg, np.random.default_rng(0))
        args = (arr.x, arr.valid, arr.goal(np.arange(2)), *sub)
        _, aux, g1 = grad_fn(params, np.float64(50.0), np.float64(0.1), *args)
        _, _, g0 = grad_fn(params, np.float64(0.0), np.float64(0.1), *args)
    assert float(aux[2]) > 0.0
    diff = [float(np.abs(np.asarray(a) - np.asarray(b)).sum()) for a, b in
            zip(jax.tree_util.tree_leaves(g1), jax.tree_util.tree_leaves(g0))]
    assert all(np.isfinite(diff)) and diff[0] > 0.0


def test_config_checks_net_and_imitate(tmp_path):
    for key, val, msg in (("net", "graph", "'net' must be one of"), ("imitate", -1.0, "imitate >= 0")):
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps({key: val}))
        with pytest.raises(T.ConfigError, match=f"bad.json.*{msg}"):
            T.load_config(str(bad))


def test_config_checks_sample_and_fidelity(tmp_path):
    for extra, msg in (({"sample": "rows"}, "'sample' must be one of"),
                       ({"sample": "layers", "net": "volume"}, "sample 'layers' needs net 'layers' and lam 0"),
                       ({"sample": "layers", "net": "layers", "lam": 10.0}, "sample 'layers' needs net 'layers'"),
                       ({"fidelity": -1.0}, "fidelity >= 0")):
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps(extra))
        with pytest.raises(T.ConfigError, match=f"bad.json.*{msg}"):
            T.load_config(str(bad))


def test_layer_samples_are_the_non_empty_layers_and_the_net_sees_them_alike(tmp_path):
    """``Arrays.layer_samples``: one sample per non-empty layer, each the
    shape's own slice; the net's logits of a sample are the shape's at that
    layer (each layer is its own), so training on samples trains the same
    function."""
    cfg = _cfg(tmp_path, sample="layers")
    shapes = [procedural_shape(i, kind=k) for i, k in enumerate(("cantilever", "tee"))]
    arr = T.shape_arrays(shapes, cfg)
    ls = arr.layer_samples()
    nonempty = [(s, z) for s in range(2) for z in range(arr.target.shape[3]) if arr.target[s, :, :, z].any()]
    assert len(ls.names) == len(nonempty) and ls.x.shape[0] == len(nonempty)
    assert ls.x.shape[1:] == arr.x.shape[1:3] + (1, layers.N_FEATURES)
    for i, (s, z) in enumerate(nonempty):
        assert ls.names[i] == f"{arr.names[s]}@z{z}"
        np.testing.assert_array_equal(ls.offset[i], arr.offset[s] + [0, 0, z])
        for k in ("x", "valid", "target", "teacher", "span"):
            np.testing.assert_array_equal(getattr(ls, k)[i, :, :, 0], getattr(arr, k)[s, :, :, z])
    params = T.initial_params(cfg, 0)
    probs_fn = T.make_fns(cfg)[0]
    whole = np.asarray(probs_fn(params, arr.x, arr.valid))
    each = np.asarray(probs_fn(params, ls.x, ls.valid))
    for i, (s, z) in enumerate(nonempty):
        np.testing.assert_allclose(each[i, :, :, 0], whole[s, :, :, z], rtol=1e-6, atol=1e-7)


def test_fidelity_zero_leaves_the_cross_entropy_and_training_on_layers_runs(tmp_path):
    cfg = _cfg(tmp_path, sample="layers", fidelity=0.0, bin_weight=0.0, bin_weight_final=0.0, batch=4)
    shapes = [procedural_shape(i, kind=k) for i, k in enumerate(("cantilever", "tee"))]
    arr = T.shape_arrays(shapes, cfg).layer_samples()
    b = np.arange(4)
    params = T.initial_params(cfg, 0)
    none = (None, None, None, None)
    with one_blas_thread():
        fid = float(T.make_fns(cfg)[3](params, arr.x[b], arr.valid[b], arr.goal(b), *none)[0])
        nothing = float(T.make_fns(dict(cfg, imitate=0.0))[3](params, arr.x[b], arr.valid[b], arr.goal(b)[0],
                                                             *none)[0])
        both = float(T.make_fns(dict(cfg, fidelity=1.0))[3](params, arr.x[b], arr.valid[b], arr.goal(b), *none)[0])
    assert nothing == 0.0  # no coverage term, no cross-entropy: nothing left
    assert 0.0 < fid < both
    # the cross-entropy by hand: summed over each sample's valid placements, a mean over the samples
    p = np.asarray(T.make_fns(cfg)[0](params, arr.x[b], arr.valid[b]), np.float64)
    t, v = arr.teacher[b], arr.valid[b]
    bce = np.where(v, -(t * np.log(np.where(v, p, 0.5)) + (~t) * np.log1p(-p)), 0.0)
    np.testing.assert_allclose(fid, bce.reshape(4, -1).sum(1).mean(), rtol=1e-9)
    run = str(tmp_path / "run")
    assert main(["train", "--config", str(tmp_path / "cfg.json"), "--out", run]) == 0
    hist = json.load(open(os.path.join(run, "history.json")))
    assert hist["config"]["sample"] == "layers" and hist["history"][-1]["step"] == 3


def test_init_starts_from_a_checkpoints_parameters(tmp_path, capsys):
    """``init`` (``train --init``): a run starts from another run's parameters
    with a fresh optimizer; another network, or a missing file, is a one-line
    error naming the file, and nothing is written."""
    cfg = _cfg(tmp_path)
    first = str(tmp_path / "first")
    with one_blas_thread():
        T.train(cfg, first, log=open(os.devnull, "w"))
    ckpt = os.path.join(first, "checkpoint.npz")
    trained = T.load_checkpoint(ckpt)[0]
    start, _ = T.train(_cfg(tmp_path, init=ckpt, lr=0.5), str(tmp_path / "second"), max_steps=0,
                       log=open(os.devnull, "w"))
    for a, b in zip(jax.tree_util.tree_leaves(start), jax.tree_util.tree_leaves(trained)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # and on through the CLI, one step: it moves away from them
    run = str(tmp_path / "tuned")
    assert main(["train", "--config", str(tmp_path / "cfg.json"), "--init", ckpt, "--steps", "1", "--out", run]) == 0
    tuned = T.load_checkpoint(os.path.join(run, "checkpoint.npz"))
    assert tuned[2] == 1 and tuned[4]["init"] == os.path.abspath(ckpt)
    assert any(not np.array_equal(np.asarray(a), np.asarray(b)) for a, b in
               zip(jax.tree_util.tree_leaves(tuned[0]), jax.tree_util.tree_leaves(trained)))
    capsys.readouterr()
    (tmp_path / "wide.json").write_text(json.dumps(dict(TINY, width=12)))
    for config, init, msg in (("wide.json", ckpt, "init checkpoint has another network: width 8 .run: 12."),
                              ("cfg.json", str(tmp_path / "nope.npz"), "init checkpoint .* not found")):
        out = tmp_path / f"bad_{config}"
        assert main(["train", "--config", str(tmp_path / config), "--init", init, "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and re.search(msg, err[0]) and not out.exists(), err
