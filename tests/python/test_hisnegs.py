# SPDX-License-Identifier: Apache-2.0
"""The Python module against the command line it shares its library with: array
shapes and dtypes, views against copies, errors as exceptions with the CLI's
messages, renders and ground truth bit for bit `hisnegs render` / `hisnegs gt`'s,
the Objective's gradient against finite differences, Ctrl-C. Run by ctest
(Python.pytest) with PYTHONPATH at the build tree's package and HISNEGS_EXE at the
`hisnegs` program."""

import os
import signal
import subprocess
import sys

import numpy as np
import pytest
import tifffile

import hisnegs

HISNEGS = os.environ.get("HISNEGS_EXE", "hisnegs")

# A small, quick fit: no time limit, a fixed schedule (the result is a pure function
# of the stack and these options).
FIT = dict(gaussians=120, rounds=2, iterations_per_round=6, time_budget_s=0)


def run_cli(*args, cwd):
    done = subprocess.run([HISNEGS, *map(str, args)], cwd=cwd, capture_output=True, text=True)
    return done


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A synthetic neuron stack (hisnegs synth), a model fitted to it by the CLI, and
    48 x 48 evaluation cameras."""
    d = tmp_path_factory.mktemp("hisnegs")
    assert run_cli("-q", "synth", "-o", d / "s.tif", "--shape", "16,48,56", cwd=d).returncode == 0
    (d / "fit.yaml").write_text(
        "gmf: {gaussians: 120, rounds: 2, iterations_per_round: 6, time_budget_s: 0}\n"
        "camera: {width: 48, height: 48}\n")
    done = run_cli("-q", "--config", d / "fit.yaml", "fit", d / "s.tif", "-o", d / "m.ply", cwd=d)
    assert done.returncode == 0, done.stderr
    hisnegs.Cameras.orbit("eval", width=48, height=48).save(d / "cameras.json")
    return d


def test_load_volume_is_a_normalized_float32_view(work):
    v = hisnegs.load_volume(work / "s.tif")
    a = v.array
    assert a.shape == v.shape == (16, 48, 56)
    assert a.dtype == np.float32
    assert a.min() == 0.0 and a.max() == 1.0
    assert np.shares_memory(a, v.array), "array must be a view of the volume, not a copy"
    assert len(v.spacing_um) == 3 and len(v.aspect) == 3
    assert max(v.aspect) == pytest.approx(1.0)
    assert "minmax" in v.normalization


def test_volume_from_array_normalizes_like_a_file(work):
    raw = tifffile.imread(work / "s.tif")
    v = hisnegs.Volume.from_array(raw, spacing_um=(0.5, 0.5, 2.0))
    assert v.spacing_um == (0.5, 0.5, 2.0)
    assert np.array_equal(v.array, hisnegs.load_volume(work / "s.tif").array)
    with pytest.raises(ValueError, match="3"):
        hisnegs.Volume.from_array(np.zeros((4, 4)))
    bad = raw.astype(np.float32)
    bad[3, 2, 1] = np.nan
    with pytest.raises(ValueError, match=r"numpy array: voxel \(x=1, y=2, z=3\) is nan; expected finite values"):
        hisnegs.Volume.from_array(bad)
    # An array numpy cannot convert: numpy's reason, not only "does not convert".
    strings = np.full((2, 3, 4), "x", dtype=object)
    with pytest.raises(ValueError, match=r"the array of 24 values \(.* as float32\) does not convert to float32: "
                                         r".*could not convert string to float"):
        hisnegs.Volume.from_array(strings)


def test_errors_are_value_errors_with_the_cli_messages(work):
    with pytest.raises(ValueError, match="no_such.tif"):
        hisnegs.load_volume(work / "no_such.tif")
    with pytest.raises(ValueError) as python_error:
        hisnegs.load_volume(work / "s.tif", normalization="bogus")
    (work / "bad.yaml").write_text("volume: {normalization: bogus}\n")
    cli = run_cli("--config", work / "bad.yaml", "info", work / "s.tif", cwd=work)
    assert cli.returncode != 0
    # The same rule, worded the same way, whichever way the option came in.
    rule = str(python_error.value).split("volume.normalization", 1)[1]
    assert "volume.normalization" + rule in cli.stderr, (str(python_error.value), cli.stderr)
    with pytest.raises(ValueError, match="gmf.gaussians"):
        hisnegs.fit(hisnegs.load_volume(work / "s.tif"), gaussians=-3)


def test_a_model_written_to_nan_is_refused_by_what_renders_or_writes_it(work, tmp_path):
    model = hisnegs.Model.load(work / "m.ply")
    model.params[3, 0] = np.nan  # params is a writable view
    cameras = hisnegs.Cameras.load(work / "cameras.json")
    calls = [("hisnegs.Model.render", lambda: model.render(cameras)),
             ("hisnegs.Model.save", lambda: model.save(tmp_path / "m.ply")),
             ("hisnegs.export_html", lambda: hisnegs.export_html(model, tmp_path / "m.html", float32=True)),
             ("hisnegs.export_compact", lambda: hisnegs.export_compact(model, tmp_path / "m.hgs")),
             ("hisnegs.export_vdb", lambda: hisnegs.export_vdb(model, tmp_path / "m.vdb"))]
    for name, call in calls:
        pattern = name.replace(".", r"\.") + r": the .* of Gaussian 3 \(nan\) is not finite"
        with pytest.raises(ValueError, match=pattern):
            call()
    assert list(tmp_path.iterdir()) == []


def test_objects_made_with_new_alone_are_refused():
    # pybind11 would hand uninitialised memory to the call (a segfault, or a garbage len).
    for cls in (hisnegs.Model, hisnegs.Cameras, hisnegs.Volume):
        obj = cls.__new__(cls)
        with pytest.raises(TypeError, match="never initialised"):
            len(obj) if cls is not hisnegs.Volume else obj.shape
    with pytest.raises(TypeError, match="never initialised"):
        hisnegs.Model.__new__(hisnegs.Model).render(hisnegs.Cameras.orbit("eval"))


def test_a_fifo_is_refused_not_waited_on(tmp_path):
    fifo = tmp_path / "f.tif"
    os.mkfifo(fifo)  # opening it for reading would block until a writer came
    with pytest.raises(ValueError, match="not a regular file"):
        hisnegs.load_volume(fifo)


def test_fit_matches_the_cli_and_params_are_a_view(work):
    lines = []
    model = hisnegs.fit(hisnegs.load_volume(work / "s.tif"), progress=lines.append, **FIT)
    assert any(line.startswith("fit: final model: 3D PSNR") for line in lines), lines
    cli = hisnegs.Model.load(work / "m.ply")
    assert len(model) == len(cli) > 0
    p = model.params
    assert p.shape == (len(model), 11) and p.dtype == np.float32
    assert np.array_equal(p, cli.params), "the same fit as `hisnegs fit` with the same options"
    p[0, 0] += 0.25
    assert model.params[0, 0] == p[0, 0], "params must be a writable view of the model"
    assert model.aggregation in ("sum", "softmax", "max")  # max: the fit ended on its hard share


def test_fit_from_a_model_matches_the_cli_init(work, tmp_path):
    start = hisnegs.Model.load(work / "m.ply")
    lines = []
    model = hisnegs.fit(hisnegs.load_volume(work / "s.tif"), progress=lines.append, init=start, **FIT)
    assert any("Gaussians from init" in line for line in lines), lines
    done = run_cli("-q", "--config", work / "fit.yaml", "fit", work / "s.tif", "--init", work / "m.ply",
                   "-o", tmp_path / "w.ply", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert np.array_equal(model.params, hisnegs.Model.load(tmp_path / "w.ply").params), "the same as `fit --init`"
    assert run_cli("-q", "synth", "-o", tmp_path / "o.tif", "--shape", "16,48,112", cwd=tmp_path).returncode == 0
    with pytest.raises(ValueError, match="init: is a model of the world box"):
        hisnegs.fit(hisnegs.load_volume(tmp_path / "o.tif"), init=start, **FIT)


def test_big_model_script_places_rotated_copies_of_real_fits(work, tmp_path):
    """scripts/big_model.py (the whole-brain stand-in of docs/benchmarks.md), small:
    every copy is the model turned and moved (its covariances turned alike)."""
    script = os.path.join(os.path.dirname(__file__), "..", "..", "scripts", "big_model.py")
    done = subprocess.run([sys.executable, script, str(tmp_path / "big.ply"), str(work / "m.ply"), "--copies", "5",
                           "--seed", "3"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    one, big = hisnegs.Model.load(work / "m.ply"), hisnegs.Model.load(tmp_path / "big.ply")
    k = len(one)
    assert len(big) == 5 * k
    p = one.params.astype(np.float64)

    def covariances(params):
        q = params[:, 6:10] / np.linalg.norm(params[:, 6:10], axis=1, keepdims=True)
        w, x, y, z = q.T
        r = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                      2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                      2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1).reshape(-1, 3, 3)
        s = np.exp(params[:, 3:6])
        return r @ (s[:, :, None] ** 2 * np.transpose(r, (0, 2, 1)))

    for c in range(5):
        copy = big.params[c * k:(c + 1) * k].astype(np.float64)
        assert np.array_equal(copy[:, 3:6], p[:, 3:6]) and np.array_equal(copy[:, 10], p[:, 10])
        a, b = p[:, :3] - p[:, :3].mean(axis=0), copy[:, :3] - copy[:, :3].mean(axis=0)
        u, _, vt = np.linalg.svd(a.T @ b)
        rot = (u @ vt).T
        assert np.linalg.det(rot) > 0 and np.abs(a @ rot.T - b).max() < 1e-5
        assert np.abs(covariances(copy) - rot @ covariances(p) @ rot.T).max() < 1e-6 * np.abs(covariances(p)).max() + 1e-12
    done = run_cli("export", "hierarchy", "--model", tmp_path / "big.ply", "-o", tmp_path / "big.hgw", "--page", "64",
                   cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert len(hisnegs.Model.load(tmp_path / "big.hgw")) == 5 * k


def test_model_save_and_load_round_trip(work, tmp_path):
    model = hisnegs.Model.load(work / "m.ply")
    model.save(tmp_path / "copy.ply")
    again = hisnegs.Model.load(tmp_path / "copy.ply")
    assert np.array_equal(again.params, model.params)
    model.save(tmp_path / "copy.hgs")  # the compact format: quantized and in Morton order, so close, not equal
    compact = hisnegs.Model.load(tmp_path / "copy.hgs")
    assert compact.params.shape == model.params.shape
    centres = compact.params[:, None, :3] - model.params[None, :, :3]
    assert np.sqrt((centres ** 2).sum(axis=2)).min(axis=1).max() < 1e-3  # every centre has its original nearby
    assert (tmp_path / "copy.hgs").read_bytes()[:4] != b"ply\n"
    (tmp_path / "broken.ply").write_text("not a ply\n")
    with pytest.raises(ValueError, match="broken.ply"):
        hisnegs.Model.load(tmp_path / "broken.ply")


def test_cameras(work, tmp_path):
    eval_views = hisnegs.Cameras.orbit("eval", width=48, height=48)
    assert len(eval_views) == 30 and (eval_views.width, eval_views.height) == (48, 48)
    assert len(hisnegs.Cameras.orbit("train")) == 106
    eval_views.save(tmp_path / "c.json")
    assert hisnegs.Cameras.load(tmp_path / "c.json").names == eval_views.names
    assert len(hisnegs.Cameras.custom([0, 30], [0, 90, 180])) == 6
    with pytest.raises(ValueError, match="kind"):
        hisnegs.Cameras.orbit("sideways")
    with pytest.raises(ValueError, match="camera.width"):
        hisnegs.Cameras.orbit("eval", width=-1)


@pytest.mark.parametrize("mode", ["hard", "soft"])
def test_render_equals_the_cli_bit_for_bit(work, mode):
    model = hisnegs.Model.load(work / "m.ply")
    cameras = hisnegs.Cameras.load(work / "cameras.json")
    images = model.render(cameras, mode=mode, beta=50, backend="cpu")
    assert images.shape == (30, 48, 48) and images.dtype == np.float32
    done = run_cli("-q", "render", "--model", work / "m.ply", "--cameras", work / "cameras.json", "--mode", mode,
                   "--beta", "50", "--backend", "cpu", "-o", work / ("r" + mode), cwd=work)
    assert done.returncode == 0, done.stderr
    assert np.array_equal(images, tifffile.imread(work / ("r" + mode) / "render.tif"))


def test_ground_truth_equals_the_cli_bit_for_bit(work):
    volume = hisnegs.load_volume(work / "s.tif")
    cameras = hisnegs.Cameras.load(work / "cameras.json")
    mips = hisnegs.ground_truth(volume, cameras, backend="cpu")
    assert mips.shape == (30, 48, 48)
    done = run_cli("-q", "gt", work / "s.tif", "-o", work / "gt", "--cameras", work / "cameras.json", "--backend",
                   "cpu", cwd=work)
    assert done.returncode == 0, done.stderr
    assert np.array_equal(mips, tifffile.imread(work / "gt" / "mips.tif"))


def test_metrics_and_rasterize(work):
    model = hisnegs.Model.load(work / "m.ply")
    cameras = hisnegs.Cameras.load(work / "cameras.json")
    images = model.render(cameras, mode="hard", backend="cpu")
    same = hisnegs.metrics(images, images)
    assert same["psnr"] == np.inf and same["ssim"] == pytest.approx(1.0)
    assert same["psnr_per_view"].shape == (30,)
    truth = hisnegs.ground_truth(hisnegs.load_volume(work / "s.tif"), cameras, backend="cpu")
    assert 10 < hisnegs.metrics(images, truth)["psnr"] < 80
    with pytest.raises(ValueError, match="shapes differ"):
        hisnegs.metrics(images, images[:2])
    spoiled = images.copy()
    spoiled[1, 2, 3] = np.nan  # one NaN pixel: an error, not PSNR inf
    with pytest.raises(ValueError, match="not a finite value"):
        hisnegs.metrics(spoiled, truth)
    voxels = model.rasterize()
    assert voxels.shape == (16, 48, 56) and voxels.dtype == np.float32
    assert model.rasterize((8, 24, 28)).shape == (8, 24, 28)


def test_objective_gradient_matches_finite_differences(work):
    volume = hisnegs.load_volume(work / "s.tif")
    model = hisnegs.Model.load(work / "m.ply")
    objective = hisnegs.Objective(volume, model, aggregation="softmax", beta=20)
    x = objective.x0.copy()
    assert objective.size == x.size == 11 * len(model)
    assert objective.samples > 0
    value, gradient = objective.value_and_gradient(x)
    assert value == objective.value(x) > 0
    assert np.array_equal(gradient, objective.gradient(x))
    # Central differences on the coordinates with the largest gradients, each kind.
    picks = [int(np.argmax(np.abs(gradient[j::11]))) * 11 + j for j in range(11)]
    for i in picks:
        h = 1e-6 * max(1.0, abs(x[i]))  # small: a term ends at the cutoff δ, so f has steps there
        up, down = x.copy(), x.copy()
        up[i] += h
        down[i] -= h
        numeric = (objective.value(up) - objective.value(down)) / (2 * h)
        assert numeric == pytest.approx(gradient[i], rel=2e-3, abs=1e-6 * abs(value)), i
    with pytest.raises(ValueError, match="flat array of 11 K"):
        objective.value(x[:-1])
    # Points scipy's line searches try: a NaN, a zero quaternion (these crashed the
    # block index, exit 139), and a model holding a NaN. Each a ValueError naming it.
    bad = x.copy()
    bad[14] = np.nan
    for call in (objective.value, objective.gradient, objective.residuals, objective.jacobian):
        with pytest.raises(ValueError, match=r"x\[14\] \(Gaussian 1, parameter 3\) is nan"):
            call(bad)
    bad = x.copy()
    bad[11 + 6:11 + 10] = 0.0
    with pytest.raises(ValueError, match="Gaussian 1's quaternion .* is zero"):
        objective.gradient(bad)
    spoiled = hisnegs.Model.load(work / "m.ply")
    spoiled.params[2, 0] = np.nan
    with pytest.raises(ValueError, match="not finite"):
        hisnegs.Objective(volume, spoiled, aggregation="softmax", beta=20)
    # The max (the fit's hard share) is an aggregation of the objective too.
    assert hisnegs.Objective(volume, model, aggregation="max").value(x) > 0
    # The least-squares view of the same problem: ½ Σ r² is the value, Jᵀ r the gradient.
    r = objective.residuals(x)
    assert r.shape == (objective.samples,)
    assert 0.5 * np.dot(r, r) == pytest.approx(value, rel=1e-10)
    J = objective.jacobian(x)
    assert J.shape == (objective.samples, objective.size)
    assert np.allclose(J.T @ r, gradient, rtol=1e-8, atol=1e-10 * np.abs(gradient).max())
    for i in picks[:3]:  # a column of J against central differences of r
        h = 1e-6 * max(1.0, abs(x[i]))
        up, down = x.copy(), x.copy()
        up[i] += h
        down[i] -= h
        numeric = (objective.residuals(up) - objective.residuals(down)) / (2 * h)
        column = J[:, i].toarray().ravel()
        assert np.allclose(numeric, column, rtol=1e-3, atol=1e-4 * np.abs(column).max()), i


def test_train_equals_the_cli(work):
    cameras = hisnegs.Cameras.load(work / "cameras.json")
    volume = hisnegs.load_volume(work / "s.tif")
    truth = hisnegs.ground_truth(volume, cameras, backend="cpu")
    lines = []
    model = hisnegs.Model.load(work / "m.ply")
    trained = hisnegs.train(model, truth, cameras, progress=lines.append, backend="cpu", epochs=3, views_per_step=2,
                            keep_better_init=False)
    assert any(line.startswith("train: epoch 3/3") for line in lines), lines
    assert len(trained) == len(model) and not np.array_equal(trained.params, model.params)
    (work / "train.yaml").write_text("train: {epochs: 3, views_per_step: 2, keep_better_init: false}\n")
    done = run_cli("-q", "--config", work / "train.yaml", "gt", work / "s.tif", "-o", work / "gtt", "--cameras",
                   work / "cameras.json", "--backend", "cpu", cwd=work)
    assert done.returncode == 0, done.stderr
    done = run_cli("-q", "--config", work / "train.yaml", "train", "--init", work / "m.ply", "--data", work / "gtt",
                   "-o", work / "t", "--backend", "cpu", cwd=work)
    assert done.returncode == 0, done.stderr
    assert np.array_equal(trained.params, hisnegs.Model.load(work / "t" / "final.ply").params)
    with pytest.raises(ValueError, match="images must be"):
        hisnegs.train(model, truth[:3], cameras, backend="cpu", epochs=1)


def test_ctrl_c_interrupts_a_fit_with_keyboard_interrupt(work):
    volume = hisnegs.load_volume(work / "s.tif")

    def interrupt(line):
        os.kill(os.getpid(), signal.SIGINT)

    with pytest.raises(KeyboardInterrupt):
        hisnegs.fit(volume, progress=interrupt, **FIT)


def test_compare_optimizers_runs_a_user_optimizer_beside_the_built_ins(work, tmp_path):
    """scipy's L-BFGS-B through RoundProblem, beside Adam and the registered spg: the
    same first loss, the loss falls, the table's rows, curves and files."""
    import scipy.optimize

    volume = hisnegs.load_volume(work / "s.tif")
    seen = {}

    def lbfgsb(problem):
        seen["size"], seen["max_iterations"] = problem.size, problem.max_iterations
        assert problem.x.dtype == np.float64 and problem.x.shape == (problem.size,)
        assert np.all(problem.lower <= problem.x) and np.all(problem.x <= problem.upper)
        return scipy.optimize.minimize(problem.value_and_gradient, problem.x, jac=True, method="L-BFGS-B",
                                       bounds=problem.bounds, callback=problem.iterate,
                                       options={"maxiter": problem.max_iterations}).x

    table = hisnegs.compare_optimizers(volume, {"scipy-lbfgsb": lbfgsb}, budget_s=2, builtins=["adam", "spg"],
                                       adam_steps=30, gaussians=120, output=tmp_path / "cmp")
    names = [run["name"] for run in table["runs"]]
    assert names == ["adam", "spg", "scipy-lbfgsb"]
    assert seen["size"] % 11 == 0 and seen["max_iterations"] == 25
    first = table["runs"][0]["curve"]["loss"][0]
    for run in table["runs"]:
        assert run["failure"] == "", run
        curve = run["curve"]
        assert len(curve["loss"]) == len(curve["seconds"]) == len(curve["iteration"]) > 1
        assert curve["loss"][0] == pytest.approx(first, rel=1e-9), run["name"]  # one start for all
        assert run["final_loss"] < 0.5 * first, run["name"]
        assert run["seconds"] <= 2.5, run["name"]  # the budget, honoured through StopRound
    assert table["target_loss"] == table["runs"][0]["final_loss"]
    assert {"summary.md", "results.csv", "curves.csv", "loss_vs_time.png"} <= set(os.listdir(tmp_path / "cmp"))
    assert "scipy-lbfgsb" in (tmp_path / "cmp" / "results.csv").read_text()


def test_compare_optimizers_raises_the_optimizers_own_errors(work):
    volume = hisnegs.load_volume(work / "s.tif")

    def broken(problem):
        raise ZeroDivisionError("inside the user's optimizer")

    with pytest.raises(ZeroDivisionError, match="inside the user's optimizer"):
        hisnegs.compare_optimizers(volume, {"broken": broken}, budget_s=1, builtins=[], gaussians=120)
    with pytest.raises(ValueError, match="not callable"):
        hisnegs.compare_optimizers(volume, {"x": 3}, budget_s=1, builtins=[], gaussians=120)
    with pytest.raises(ValueError, match="built-in"):
        hisnegs.compare_optimizers(volume, {"adam": broken}, budget_s=1, builtins=[], gaussians=120)
    kept = []
    with pytest.raises(ValueError, match="after its round ended"):
        hisnegs.compare_optimizers(volume, {"keeps": lambda p: kept.append(p)}, budget_s=0.2, builtins=[],
                                   gaussians=120)
        kept[0].value(kept[0].x)


def test_exports_equal_the_cli(work, tmp_path):
    """export_compact / export_volume / export_html write what `hisnegs export` writes
    for the same model; export_vdb's points grid imports back to the same model."""
    model = hisnegs.Model.load(work / "m.ply")
    info = hisnegs.export_compact(model, tmp_path / "py.hgs")
    assert run_cli("-q", "export", "compact", "--model", work / "m.ply", "-o", tmp_path / "cli.hgs",
                   cwd=tmp_path).returncode == 0
    assert (tmp_path / "py.hgs").read_bytes() == (tmp_path / "cli.hgs").read_bytes()
    assert info["gaussians"] == len(model) and info["file_bytes"] == (tmp_path / "py.hgs").stat().st_size
    assert len(hisnegs.Model.load(tmp_path / "py.hgs")) == len(model)

    info = hisnegs.export_volume(model, tmp_path / "py.tif", match_volume=work / "s.tif")
    assert run_cli("-q", "export", "volume", "--model", work / "m.ply", "-o", tmp_path / "cli.tif",
                   "--match-volume", work / "s.tif", cwd=tmp_path).returncode == 0
    assert np.array_equal(tifffile.imread(tmp_path / "py.tif"), tifffile.imread(tmp_path / "cli.tif"))
    assert info["shape"] == (16, 48, 56) and info["psnr"] > 10

    cameras = hisnegs.Cameras.load(work / "cameras.json")
    info = hisnegs.export_html(model, tmp_path / "py.html", cameras=cameras)
    assert run_cli("-q", "export", "html", "--model", work / "m.ply", "--cameras", work / "cameras.json", "-o",
                   tmp_path / "cli.html", cwd=tmp_path).returncode == 0
    assert (tmp_path / "py.html").read_bytes() == (tmp_path / "cli.html").read_bytes()
    assert info["views"] == len(cameras) and info["page_bytes"] == (tmp_path / "py.html").stat().st_size

    info = hisnegs.export_vdb(model, tmp_path / "py.vdb", points=True)
    assert info["active_voxels"] > 0 and info["gaussians"] == len(model)
    assert run_cli("-q", "import", "vdb", tmp_path / "py.vdb", "-o", tmp_path / "back.ply",
                   cwd=tmp_path).returncode == 0
    assert np.array_equal(hisnegs.Model.load(tmp_path / "back.ply").params, model.params)

    with pytest.raises(ValueError, match="voxel_size"):
        hisnegs.export_vdb(model, tmp_path / "bad.vdb", voxel_size=-1.0)
    with pytest.raises(ValueError, match="position_bits"):
        hisnegs.export_compact(model, tmp_path / "bad.hgs", position_bits=40)
    assert not (tmp_path / "bad.vdb").exists() and not (tmp_path / "bad.hgs").exists()
    stack = tmp_path / "stack.tif"  # an export never replaces the stack it matches
    stack.write_bytes((work / "s.tif").read_bytes())
    for export in (hisnegs.export_volume, hisnegs.export_vdb):
        with pytest.raises(ValueError, match="is also the volume to match"):
            export(model, stack, match_volume=stack)
    assert stack.read_bytes() == (work / "s.tif").read_bytes()
    # Nor a file behind it: the .h5 a BigDataViewer .xml names (checked before it is read).
    h5 = tmp_path / "g.h5"
    h5.write_bytes(b"stands for the stack's data")
    (tmp_path / "g.xml").write_text('<?xml version="1.0"?><SpimData version="0.2"><SequenceDescription>'
                                    '<ImageLoader format="bdv.hdf5"><hdf5 type="relative">g.h5</hdf5></ImageLoader>'
                                    '<ViewSetups><ViewSetup><id>0</id></ViewSetup></ViewSetups>'
                                    '</SequenceDescription></SpimData>')
    for export in (hisnegs.export_volume, hisnegs.export_vdb):
        with pytest.raises(ValueError, match="is also the volume to match"):
            export(model, h5, match_volume=tmp_path / "g.xml")
    assert h5.read_bytes() == b"stands for the stack's data"


def test_info_prints_what_the_cli_prints(work):
    for name, kind in (("m.ply", "checkpoint"), ("s.tif", "stack")):
        described = hisnegs.info(work / name)
        assert described["kind"] == kind
        keys = [key for key, _ in described["rows"]]
        assert "file" in keys
        done = run_cli("info", work / name, cwd=work)
        assert done.returncode == 0, done.stderr
        if kind == "checkpoint":  # a stack's rows include its read time
            assert described["text"] == done.stdout
    with pytest.raises(ValueError, match="unrecognized file type"):
        hisnegs.info(work / "fit.yaml")
