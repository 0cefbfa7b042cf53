# SPDX-License-Identifier: Apache-2.0
# Type stubs of the hisnegs package (apps/python): what an editor completes and checks.
import os
from typing import Any, Callable, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, "os.PathLike[str]"]
_Progress = Optional[Callable[[str], None]]

class Volume:
    """A stack in memory, normalized to [0, 1]."""

    @property
    def array(self) -> npt.NDArray[np.float32]:
        """(z, y, x) float32 view of the voxels (no copy)."""
    @property
    def shape(self) -> Tuple[int, int, int]: ...
    @property
    def spacing_um(self) -> Tuple[float, float, float]:
        """Voxel size (x, y, z) in µm."""
    @property
    def aspect(self) -> Tuple[float, float, float]:
        """Half extents (x, y, z) of the world box (CONVENTIONS.md)."""
    @property
    def normalization(self) -> str: ...
    @property
    def source(self) -> str: ...
    @staticmethod
    def from_array(
        array: npt.ArrayLike, spacing_um: Optional[Sequence[float]] = None, **volume_options: Any
    ) -> "Volume":
        """A volume from a (z, y, x) array of raw values, normalized as a stack file."""

class Cameras:
    """Pinhole views of CONVENTIONS.md."""

    @staticmethod
    def load(path: _Path) -> "Cameras":
        """Reads a cameras.json."""
    @staticmethod
    def orbit(kind: str = "eval", **camera_options: Any) -> "Cameras":
        """The report's "train" (106 views) or "eval" (30 views) orbit."""
    @staticmethod
    def custom(
        elevations_deg: Sequence[float], azimuths_deg: Sequence[float], **camera_options: Any
    ) -> "Cameras": ...
    def save(self, path: _Path) -> None: ...
    def __len__(self) -> int: ...
    @property
    def width(self) -> int: ...
    @property
    def height(self) -> int: ...
    @property
    def names(self) -> list[str]: ...

class Model:
    """A mixture with its checkpoint metadata."""

    @staticmethod
    def load(path: _Path) -> "Model":
        """Reads a .ply or compact .hgs checkpoint."""
    def save(self, path: _Path) -> None:
        """Writes a .ply, or the compact checkpoint for a .hgs name."""
    def __len__(self) -> int: ...
    @property
    def params(self) -> npt.NDArray[np.float32]:
        """(K, 11) float32 view: x, y, z, log σ0..2, quaternion w x y z, intensity logit."""
    @property
    def aggregation(self) -> str:
        """"sum" or "softmax": how the terms combine in 3D."""
    @property
    def beta(self) -> float: ...
    def render(
        self,
        cameras: Cameras,
        mode: str = "soft",
        beta: float = 50.0,
        backend: str = "auto",
        background: bool = True,
        **splat_options: Any,
    ) -> npt.NDArray[np.float32]:
        """(views, height, width) MIPs, bit for bit `hisnegs render`'s."""
    def rasterize(self, shape: Optional[Sequence[int]] = None) -> npt.NDArray[np.float32]:
        """The model at every voxel centre, (z, y, x)."""

class Objective:
    """The stage-1 least-squares problem: ½ Σ w² (f(x) − V)² on the fit's samples."""

    x0: npt.NDArray[np.float64]
    def __init__(
        self,
        volume: Volume,
        model: Model,
        aggregation: str = "softmax",
        beta: float = 50.0,
        gmf_options: Optional[dict[str, Any]] = None,
        sparse_grid_options: Optional[dict[str, Any]] = None,
    ) -> None: ...
    @property
    def size(self) -> int:
        """11 K."""
    @property
    def samples(self) -> int: ...
    def value(self, x: npt.ArrayLike) -> float: ...
    def gradient(self, x: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
    def value_and_gradient(self, x: npt.ArrayLike) -> Tuple[float, npt.NDArray[np.float64]]: ...
    def residuals(self, x: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
    def jacobian(self, x: npt.ArrayLike) -> Any:
        """scipy.sparse.csr_matrix, samples × 11 K."""

class StopRound(Exception):
    """Raised by RoundProblem.iterate when the round must end; let it propagate."""

class RoundProblem:
    """One round of the stage-1 fit as a compare_optimizers optimizer sees it."""

    @property
    def size(self) -> int:
        """11 K."""
    @property
    def x(self) -> npt.NDArray[np.float64]:
        """The round's start (a copy)."""
    @property
    def lower(self) -> npt.NDArray[np.float64]: ...
    @property
    def upper(self) -> npt.NDArray[np.float64]: ...
    @property
    def bounds(self) -> list[Tuple[Optional[float], Optional[float]]]:
        """scipy.optimize's bounds of the round's box."""
    @property
    def max_iterations(self) -> int: ...
    @property
    def seconds_left(self) -> float: ...
    @property
    def iterations(self) -> int: ...
    def value(self, x: npt.ArrayLike) -> float: ...
    def gradient(self, x: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
    def value_and_gradient(self, x: npt.ArrayLike) -> Tuple[float, npt.NDArray[np.float64]]: ...
    def iterate(self, x: npt.ArrayLike) -> None:
        """One iteration ends at x: logs its loss; raises StopRound when the round must end."""

def compare_optimizers(
    volume: Volume,
    optimizers: dict[str, Callable[[RoundProblem], Optional[npt.ArrayLike]]],
    budget_s: float = 60.0,
    builtins: Sequence[str] = ("adam", "brick-lm", "lm-cgnr", "lbfgs"),
    adam_steps: int = 2000,
    stop_at_target: bool = False,
    continuation: Sequence[str] = ("brick-lm",),
    output: Optional[_Path] = None,
    progress: _Progress = None,
    sparse_grid_options: Optional[dict[str, Any]] = None,
    **gmf_options: Any,
) -> dict[str, Any]:
    """compare-optimizers with Python optimizers: the table's rows and their curves."""

def load_volume(path: _Path, **volume_options: Any) -> Volume:
    """Reads TIFF/BigTIFF, HDF5, BigDataViewer or Imaris; normalized to [0, 1]."""

def fit(volume: Volume, progress: _Progress = None, **gmf_options: Any) -> Model:
    """Stage 1: fits a Gaussian mixture (the config's gmf options)."""

def train(
    model: Model,
    images: npt.ArrayLike,
    cameras: Cameras,
    progress: _Progress = None,
    backend: str = "auto",
    splat_options: Optional[dict[str, Any]] = None,
    **train_options: Any,
) -> Model:
    """Stage 2: soft-MIP training on (views, height, width) images of the cameras."""

def ground_truth(
    volume: Volume, cameras: Cameras, backend: str = "auto", **raymarch_options: Any
) -> npt.NDArray[np.float32]:
    """Ray-marched MIPs, (views, height, width)."""

def metrics(render: npt.ArrayLike, target: npt.ArrayLike) -> dict[str, Any]:
    """PSNR, SSIM, MAE: means and per view."""

def export_vdb(
    model: Model,
    path: _Path,
    voxel_size: Optional[float] = None,
    match_volume: Optional[_Path] = None,
    cutoff: float = 1e-3,
    tail: float = 1e-8,
    points: bool = False,
    untruncated_sum: bool = False,
    mahalanobis_cutoff: Optional[float] = None,
    **volume_options: Any,
) -> dict[str, Any]:
    """`hisnegs export vdb`: a sparse OpenVDB density grid (+ points)."""

def export_volume(
    model: Model,
    path: _Path,
    match_volume: Optional[_Path] = None,
    tail: float = 1e-8,
    untruncated_sum: bool = False,
    mahalanobis_cutoff: Optional[float] = None,
    **volume_options: Any,
) -> dict[str, Any]:
    """`hisnegs export volume`: the model's f as a float32 TIFF stack."""

def export_compact(
    model: Model,
    path: _Path,
    position_bits: int = 16,
    scale_bits: int = 8,
    rotation_bits: int = 10,
    intensity_bits: int = 8,
    level: int = 19,
) -> dict[str, Any]:
    """`hisnegs export compact`: the .hgs compact checkpoint."""

def export_html(
    model: Model,
    path: _Path,
    cameras: Optional[Cameras] = None,
    float32: bool = False,
    background: bool = True,
    camera_options: Optional[dict[str, Any]] = None,
    **splat_options: Any,
) -> dict[str, Any]:
    """`hisnegs export html`: a self-contained WebGL2 viewer page."""

def info(path: _Path, **volume_options: Any) -> dict[str, Any]:
    """`hisnegs info`: kind, rows (key, text) and the printed text."""
