# SPDX-License-Identifier: Apache-2.0
"""hisnegs for Python: fit a microscopy stack with anisotropic 3D Gaussians and
render Maximum Intensity Projections of them, with numpy arrays in and out.

The same library as the ``hisnegs`` command: options are the config file's keys
(``configs/default.yaml``), with the same defaults, validation and error
messages (raised as ``ValueError``). Arrays are (z, y, x) for volumes and
(views, height, width) for images, float32. Long calls release the GIL; with a
``progress`` callable they send it each line the command would print, and
Ctrl-C raises ``KeyboardInterrupt`` at the next line.

>>> import hisnegs
>>> volume = hisnegs.load_volume("op1_neuron.tif")
>>> model = hisnegs.fit(volume, gaussians=20000, time_budget_s=60)
>>> cameras = hisnegs.Cameras.orbit("eval")
>>> images = model.render(cameras, mode="hard")          # (30, 256, 256)
>>> truth = hisnegs.ground_truth(volume, cameras)
>>> hisnegs.metrics(images, truth)["psnr"]
"""

import json as _json


def _why_not_importable(error):
    """One line saying why the compiled module cannot be used from this interpreter."""
    import glob as _glob
    import os as _os
    import sys as _sys
    try:
        from ._build_info import PYTHON as built_for, VERSION as built_version
    except ImportError:
        built_for, built_version = "the Python CMake found", "?"
    here = "%s (Python %d.%d)" % (_sys.executable, _sys.version_info[0], _sys.version_info[1])
    if not _glob.glob(_os.path.join(_os.path.dirname(__file__), "_hisnegs*.so")):
        return ("hisnegs: the compiled module _hisnegs is not built: run `cmake --build --preset release --target "
                "hisnegs_python` (it needs Python 3 with NumPy and pybind11: Debian python3-dev python3-numpy "
                "pybind11-dev)")
    if isinstance(error, ModuleNotFoundError) and error.name == "numpy":
        return ("hisnegs: this interpreter, %s, has no NumPy; the module was built for %s (Python %s): run that "
                "one (or install NumPy here)" % (here, built_for, built_version))
    if "%d.%d" % _sys.version_info[:2] != built_version:
        return ("hisnegs: the module was built for %s (Python %s), not for this interpreter, %s: run that one"
                % (built_for, built_version, here))
    return "hisnegs: the compiled module _hisnegs does not load in %s: %s" % (here, error)


try:
    import numpy as _numpy  # noqa: F401  (the module's arrays are numpy arrays)
    from . import _hisnegs
except ImportError as _error:
    raise ImportError(_why_not_importable(_error)) from None
from ._hisnegs import Cameras, Model, RoundProblem, StopRound, Volume, metrics

__all__ = ["Volume", "Model", "Cameras", "Objective", "RoundProblem", "StopRound", "load_volume", "fit", "train",
           "ground_truth", "metrics", "compare_optimizers", "export_vdb", "export_volume", "export_compact",
           "export_html", "info"]


def _sections(**sections):
    """The config text (JSON, which YAML reads) of the sections given options; "" for none."""
    given = {name: options for name, options in sections.items() if options}
    return _json.dumps(given) if given else ""


def load_volume(path, **volume_options):
    """Reads a stack (TIFF/BigTIFF, HDF5, BigDataViewer .xml, Imaris .ims), normalizes
    it to [0, 1] and places it in the world box, as every command does.

    ``volume_options`` are the config's ``volume`` section (``normalization``,
    ``percentile_lo``, ``spacing_um``, ``aspect``, ``channel``, ``dataset``,
    ``timepoint``, ...). Returns a :class:`Volume`."""
    return _hisnegs._load_volume(str(path), _sections(volume=volume_options))


def _volume_from_array(array, spacing_um=None, **volume_options):
    """A :class:`Volume` from a (z, y, x) array of raw values (any real dtype; copied
    as float32), normalized as a stack file would be. ``spacing_um`` is the voxel
    size (x, y, z) in µm (default 1 µm)."""
    if spacing_um is not None:
        volume_options["spacing_um"] = [float(s) for s in spacing_um]
    return _hisnegs._volume_from_array(array, _sections(volume=volume_options))


Volume.from_array = staticmethod(_volume_from_array)
Volume.__doc__ = """A stack in memory, normalized to [0, 1] (``load_volume``, ``Volume.from_array``).

``array``: a (z, y, x) float32 view of its voxels (no copy; it keeps the volume
alive); ``shape`` (z, y, x); ``spacing_um`` (x, y, z); ``aspect``: the world
box's half extents (x, y, z) of CONVENTIONS.md; ``normalization``: the map that
was applied; ``source``: the file or "numpy array"."""


def fit(volume, progress=None, init=None, **gmf_options):
    """Fits a Gaussian mixture to ``volume`` (stage 1), as ``hisnegs fit`` does for a
    stack in memory: the config's ``gmf`` section as keyword options (``gaussians``,
    ``time_budget_s``, ``optimizer``, ``aggregation``, ``seed``, ...). Returns a
    :class:`Model` with its checkpoint metadata (frame, normalization, background).
    ``progress``: a callable taking each line. ``init``: a :class:`Model` of the same
    stack to start from (``fit --init``: a coarser level's fit, or an earlier one)."""
    return _hisnegs._fit(volume, _sections(gmf=gmf_options), progress, init)


def train(model, images, cameras, progress=None, backend="auto", splat_options=None, **train_options):
    """Stage 2: trains ``model`` on ``images`` (views, height, width), the MIPs of
    ``cameras``' views (e.g. ``ground_truth(volume, cameras)``), as ``hisnegs train``
    does: the config's ``train`` section as keyword options (``epochs``,
    ``views_per_step``, ``lr_initial``, ...; on the CPU back end with none given, the
    CPU schedule), ``train.keep_better_init`` included. Returns a new :class:`Model`."""
    text = _sections(train=train_options, splat=splat_options or {})
    return _hisnegs._train(model, images, cameras, text, backend, progress)


def _orbit(kind="eval", **camera_options):
    """The report's orbits: ``"train"`` (106 views) or ``"eval"`` (30 views), with
    the config's ``camera`` section as options (``width``, ``height``, ``fov_deg``,
    ``orbit_radius``, ...)."""
    return _hisnegs._orbit_cameras(kind, _sections(camera=camera_options))


def _custom(elevations_deg, azimuths_deg, **camera_options):
    """Every elevation × azimuth (degrees), elevation-major, on the orbit sphere."""
    return _hisnegs._custom_cameras([float(e) for e in elevations_deg], [float(a) for a in azimuths_deg],
                                    _sections(camera=camera_options))


Cameras.orbit = staticmethod(_orbit)
Cameras.custom = staticmethod(_custom)
Cameras.__doc__ = """Pinhole views of CONVENTIONS.md: ``Cameras.load(path)`` (a cameras.json),
``Cameras.orbit(kind)``, ``Cameras.custom(elevations, azimuths)``; ``save(path)``,
``len()``, ``width``, ``height``, ``names``."""


def _render(self, cameras, mode="soft", beta=50.0, backend="auto", background=True, **splat_options):
    """Renders the model's MIP in every view of ``cameras``: ``mode`` "soft" (the
    softmax of Eq. 8 at ``beta``) or "hard" (the max), over the background floor the
    model records unless ``background=False``. Returns (views, height, width)
    float32, equal bit for bit to ``hisnegs render`` of the same model, cameras and
    options on the same back end."""
    options = dict(splat_options, mode=mode, beta=float(beta), background=bool(background))
    return self._render(cameras, _sections(splat=options), backend)


def _rasterize(self, shape=None):
    """The model's value at every voxel centre: of the volume it was fitted to, or of
    a (z, y, x) ``shape`` spanning the same world box. Returns float32 (z, y, x)."""
    return self._rasterize(None if shape is None else [int(s) for s in shape])


Model.render = _render
Model.rasterize = _rasterize
Model.__doc__ = """A fitted or trained mixture with its checkpoint metadata.

``Model.load(path)`` reads a .ply or compact .hgs checkpoint; ``save(path)`` writes a .ply, or
with a .hgs name the compact checkpoint (``export_compact``'s defaults; ``export_compact`` sets the bits).
``params``: a (K, 11) float32 view of the parameters in the checkpoint's order:
x, y, z (world), log σ0, log σ1, log σ2, quaternion w, x, y, z (unnormalized),
intensity logit; writing it changes the model. ``aggregation`` and ``beta``: how
the model's terms combine in 3D ("max" after a default fit, which ends on the max;
``beta`` is then 0)."""


def ground_truth(volume, cameras, backend="auto", **raymarch_options):
    """The ray-marched MIPs of ``volume`` in every view of ``cameras`` (what ``hisnegs
    gt`` writes as mips.tif), with the config's ``raymarch`` section as options.
    Returns (views, height, width) float32."""
    return _hisnegs._ground_truth(volume, cameras, _sections(raymarch=raymarch_options), backend)


class Objective:
    """The stage-1 least-squares problem of the fit on ``volume``: its samples and
    weights (the sparse grid with ``gmf.background_fraction``, at the voxel centres),
    ½ Σ w² (f(x) − V)² with f the mixture under ``aggregation`` ("softmax" at
    ``beta``, "max" (its subgradient), or "sum"), for a flat float64 ``x`` of 11 K values in the order of
    ``Model.params`` (K = the model's Gaussians). ``value(x)``, ``gradient(x)`` and
    ``value_and_gradient(x)`` (for scipy.optimize(jac=True)), ``residuals(x)`` and
    ``jacobian(x)`` (scipy.sparse CSR; for least-squares solvers). Each call with a new x
    rebuilds the index of which Gaussians reach which samples, so x may move freely.
    ``gmf_options`` and ``sparse_grid_options`` are the config's sections."""

    def __init__(self, volume, model, aggregation="softmax", beta=50.0, gmf_options=None, sparse_grid_options=None):
        text = _sections(gmf=gmf_options or {}, sparse_grid=sparse_grid_options or {})
        self._core = _hisnegs._Objective(volume, model, text, aggregation, float(beta))
        self.x0 = model.params.astype("float64").ravel()

    @property
    def size(self):
        """The length of x: 11 K."""
        return self._core.size

    @property
    def samples(self):
        """The number of samples (residuals)."""
        return self._core.samples

    def value(self, x):
        return self._core.value(x)

    def gradient(self, x):
        return self._core.gradient(x)

    def value_and_gradient(self, x):
        return self._core.value_and_gradient(x)

    def residuals(self, x):
        """r_j = w_j (f(x_j) − V_j) of every sample: ½ Σ r² is value(x)."""
        return self._core.residuals(x)

    def jacobian(self, x):
        """∂r/∂x as a scipy.sparse CSR matrix (samples × 11 K): row j holds the 11
        columns of each Gaussian that may reach sample j (explicit zeros where one
        does not); Jᵀ r is gradient(x)."""
        import scipy.sparse

        values, columns, rows = self._core.jacobian(x)
        return scipy.sparse.csr_matrix((values, columns, rows), shape=(self.samples, self.size))


RoundProblem.__doc__ = """One round of the stage-1 fit as a ``compare_optimizers`` optimizer sees it
(valid only during its call; the C++ interface is gmf/round_solver.hpp).

``x``: the round's start, a flat float64 array of 11 K values in the order of
``Model.params`` (a copy); ``lower``, ``upper``: the round's box (its trust
region; ±inf where free) and ``bounds`` the same as scipy's (lo, hi) pairs;
``value(x)``, ``gradient(x)``, ``value_and_gradient(x)``: the loss
½ Σ w² (f − V)² on the round's samples at the fit's β, and its gradient (the
function every built-in optimizer minimizes); ``max_iterations`` and
``seconds_left``: the round's limits.

Call ``iterate(x)`` once per iteration with the new iterate: it logs the loss at x
(free when x was the last point evaluated) with the wall clock, and raises
``StopRound`` when the round must end (its time is spent or the loss reached the
target); let it propagate. The round's result is the optimizer's return value (a
flat array), or with ``None`` or a ``StopRound`` the last iterate; it is clamped
into the box. The round's start is logged before the call, as every built-in
optimizer logs its iteration 0."""


def compare_optimizers(volume, optimizers, budget_s=60.0, builtins=("adam", "brick-lm", "lm-cgnr", "lbfgs"),
                       adam_steps=2000, stop_at_target=False, continuation=("brick-lm",), output=None,
                       progress=None, sparse_grid_options=None, **gmf_options):
    """Runs ``hisnegs compare-optimizers`` on ``volume`` with your optimizers beside the
    built-in ones: every run from the same initialization, samples, loss and budget
    (``budget_s`` seconds of wall time each), density control off; Adam first, its
    loss after ``adam_steps`` is the target.

    ``optimizers``: ``{"name": callable}``; each callable is called once per round
    with a :class:`RoundProblem` and returns the round's result (or None).
    ``builtins``: the built-in (adam, brick-lm, lm-cgnr, lbfgs, lm, dogleg) and
    registered (e.g. spg) optimizers to run too; ``continuation``: those of them that
    follow the β schedule (the others, and every callable, solve at ``beta_end``).
    ``gmf_options``: the config's ``gmf`` section (``gaussians``, ``beta_end``, ...).
    With ``output`` (a folder) the command's files are written there too:
    summary.md, results.csv, curves.csv, loss_vs_time.png.

    Returns ``{"target_loss", "adam_steps_done", "runs": [...]}``, a run being the
    table's row (``name``, ``seconds_to_target``, ``final_loss``, ``final_psnr_3d``,
    ``iterations``, ``seconds``, ``gaussians``, ``stop_reason``, ``continuation``,
    ``failure``) and its ``curve`` (``seconds``, ``loss``, ``iteration`` arrays).

    >>> import scipy.optimize
    >>> def lbfgsb(problem):
    ...     return scipy.optimize.minimize(problem.value_and_gradient, problem.x, jac=True,
    ...         method="L-BFGS-B", bounds=problem.bounds, callback=problem.iterate,
    ...         options={"maxiter": problem.max_iterations}).x
    >>> table = hisnegs.compare_optimizers(volume, {"scipy-lbfgsb": lbfgsb}, budget_s=60)
    """
    text = _sections(gmf=gmf_options, sparse_grid=sparse_grid_options or {})
    return _hisnegs._compare_optimizers(volume, [str(b) for b in builtins], dict(optimizers), text, float(budget_s),
                                        int(adam_steps), bool(stop_at_target), [str(c) for c in continuation],
                                        "" if output is None else str(output), progress)


def export_vdb(model, path, voxel_size=None, match_volume=None, cutoff=1e-3, tail=1e-8, points=False,
               untruncated_sum=False, mahalanobis_cutoff=None, **volume_options):
    """``hisnegs export vdb``: the model's f as a sparse OpenVDB ``density`` grid (voxels
    with f > ``cutoff`` active), on the model's own stack voxels, those of
    ``match_volume`` (its header only; ``volume_options`` say how to read it) or cubic
    voxels of ``voxel_size`` world units; ``points`` adds the ``gaussians``
    PointDataGrid (``hisnegs import vdb`` reads it back exactly). The support δ is
    ``mahalanobis_cutoff`` (default the config's ``gmf.mahalanobis_cutoff``, as the fit had
    it). Returns the report (``active_voxels``, ``leaves``, ``gaussians``,
    ``file_bytes``, ``lattice``, ``function``)."""
    gmf = {} if mahalanobis_cutoff is None else {"mahalanobis_cutoff": float(mahalanobis_cutoff)}
    return _hisnegs._export_vdb(model, str(path), None if voxel_size is None else float(voxel_size),
                                "" if match_volume is None else str(match_volume), float(cutoff), float(tail),
                                bool(points), bool(untruncated_sum), _sections(volume=volume_options, gmf=gmf))


def export_volume(model, path, match_volume=None, tail=1e-8, untruncated_sum=False, mahalanobis_cutoff=None,
                  **volume_options):
    """``hisnegs export volume``: the model's f at every voxel centre of its own stack (or
    of ``match_volume``, then with the 3D PSNR against it) as a float32 TIFF stack.
    Returns ``shape`` (z, y, x), ``psnr`` (or None) and ``function``."""
    gmf = {} if mahalanobis_cutoff is None else {"mahalanobis_cutoff": float(mahalanobis_cutoff)}
    return _hisnegs._export_volume(model, str(path), "" if match_volume is None else str(match_volume), float(tail),
                                   bool(untruncated_sum), _sections(volume=volume_options, gmf=gmf))


def export_compact(model, path, position_bits=16, scale_bits=8, rotation_bits=10, intensity_bits=8, level=19):
    """``hisnegs export compact``: the compact checkpoint (.hgs: quantized, zstd) that
    every command and ``Model.load`` read like the .ply. Returns ``gaussians``,
    ``file_bytes``, ``bytes_per_gaussian`` and the largest quantization errors
    (``max_error``)."""
    return _hisnegs._export_compact(model, str(path), int(position_bits), int(scale_bits), int(rotation_bits),
                                    int(intensity_bits), int(level))


def export_html(model, path, cameras=None, float32=False, background=True, camera_options=None, **splat_options):
    """``hisnegs export html``: one self-contained HTML file, a WebGL2 hard-MIP viewer
    with the model and ``cameras`` (default: the evaluation orbit of
    ``camera_options``) inside; ``#view=N&ui=0`` shows view N. ``float32`` embeds exact
    parameters instead of the compact encoding. Returns ``page_bytes``,
    ``model_bytes`` and ``views``."""
    splat = dict(splat_options, background=bool(background))
    return _hisnegs._export_html(model, str(path), cameras, bool(float32),
                                 _sections(splat=splat, camera=camera_options or {}))


def info(path, **volume_options):
    """``hisnegs info``: what a stack (TIFF, HDF5, BigDataViewer, Imaris), an OpenVDB
    file or a checkpoint (.ply, .hgs) holds. Returns ``kind`` ("stack", "vdb",
    "checkpoint", "compact checkpoint"), ``rows`` ((key, text) in order; key "" for
    a line of its own) and ``text`` (what the command prints)."""
    return _hisnegs._info(str(path), _sections(volume=volume_options))
