// SPDX-License-Identifier: Apache-2.0
// The Volume type (a dense Z×Y×X float stack with its spacing and provenance),
// normalization, aspect scales, index<->world transforms and trilinear sampling,
// exactly as ../shared/CONVENTIONS.md ("Volume", "World space") defines them.
// Knows nothing of file formats (tiff_stack.hpp) or of Gaussians.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace hisnegs::io {

// Sample type a stack was stored with. Values are always held as float32.
enum class SampleType { kUint8, kUint16, kFloat32 };
[[nodiscard]] std::string_view to_string(SampleType type);

// Where one axis' spacing came from, in CONVENTIONS precedence order.
enum class SpacingSource {
  kDefault,           // nothing stored: 1 µm
  kUser,              // command line or config
  kOmeXml,            // OME-XML PhysicalSize{X,Y,Z}
  kImageJSpacing,     // ImageJ description `spacing=` (z)
  kImageJResolution,  // X/YResolution with the ImageJ description's `unit=`
  kTiffResolution,    // X/YResolution with ResolutionUnit = centimeter
  kFile,              // a hisnegs file's own metadata (.vdb, .ply)
  kHdf5,              // HDF5 metadata: element_size_um, BigDataViewer's voxelSize, Imaris' extents
  kOmeZarr,           // OME-Zarr multiscales: the level's scale and the axes' units
};
[[nodiscard]] std::string_view to_string(SpacingSource source);

// The voxel sizes hisnegs takes, in µm: 1 pm to 1 m, wider than any microscope (EM
// ~1 nm, light sheet ~10 µm, CT ~1 mm) and far from where the box's size or its
// square overflows a double (--spacing 1e308 made `fit` fail with a NaN box).
inline constexpr double kMinVoxelUm = 1e-6;
inline constexpr double kMaxVoxelUm = 1e6;
// "" when `um` is a voxel size in [kMinVoxelUm, kMaxVoxelUm], else what is wrong
// ("must be a voxel size in [1e-06, 1e+06] um (1 pm to 1 m)").
[[nodiscard]] std::string voxel_size_problem(double um);

// Voxel size in µm along x (columns), y (rows), z (pages), and the origin of each.
struct VoxelSpacing {
  std::array<double, 3> um{1.0, 1.0, 1.0};
  std::array<SpacingSource, 3> source{SpacingSource::kDefault, SpacingSource::kDefault, SpacingSource::kDefault};
  // "0.3296 x 0.3296 x 0.9988 µm (x, y: ImageJ X/YResolution; z: ImageJ spacing=)".
  [[nodiscard]] std::string describe() const;
};

enum class NormalizationMethod { kNone, kMinMax, kPercentile };
[[nodiscard]] std::string_view to_string(NormalizationMethod method);

// The affine map that was applied: v' = (v - raw_lo) / (raw_hi - raw_lo), and for
// kPercentile values outside [raw_lo, raw_hi] were clipped (clipped_voxels counts them).
struct Normalization {
  NormalizationMethod method = NormalizationMethod::kNone;
  double raw_lo = 0.0;
  double raw_hi = 1.0;
  std::int64_t clipped_voxels = 0;
  // "minmax 0 254" / "percentile 0.1 99.9 -> 3 1870" / "none".
  [[nodiscard]] std::string describe() const;
};

// How `normalize` maps raw values into [0, 1] (config section `volume`).
struct NormalizationOptions {
  NormalizationMethod method = NormalizationMethod::kMinMax;  // minmax | percentile
  double percentile_lo = 0.1;                                 // percent, [0, 100), lower clip for `percentile`
  double percentile_hi = 99.9;  // percent, (percentile_lo, 100], upper clip for `percentile`
  void validate() const;        // throws InputError naming the field
};

// A dense stack V[z][y][x] stored x-fastest: index = (z * ny + y) * nx + x.
struct Volume {
  int nx = 0, ny = 0, nz = 0;  // X (columns), Y (rows), Z (pages)
  std::vector<float> voxels;   // nx*ny*nz values
  SampleType stored_as = SampleType::kFloat32;
  VoxelSpacing spacing;
  Normalization normalization;  // method kNone until normalize() ran
  std::string source;           // file path or "synthetic"

  [[nodiscard]] std::size_t size() const { return static_cast<std::size_t>(nx) * ny * nz; }
  [[nodiscard]] std::size_t index(int x, int y, int z) const { return (static_cast<std::size_t>(z) * ny + y) * nx + x; }
  [[nodiscard]] float at(int x, int y, int z) const { return voxels[index(x, y, z)]; }
  [[nodiscard]] float& at(int x, int y, int z) { return voxels[index(x, y, z)]; }
};

// Rescales `volume` in place to [0, 1] (CONVENTIONS "Normalization") and records
// the map in volume.normalization. Throws InputError naming volume.source if the
// volume is constant (max == min) or holds non-finite values.
void normalize(Volume& volume, const NormalizationOptions& options);

// Applies `map` (from normalize(), or io::normalization_from for a stack read by
// regions) to raw values in place, exactly as normalize() does; returns how many
// were clipped (percentile maps). kNone leaves them.
std::int64_t apply_normalization(std::span<float> values, const Normalization& map);

// Summary statistics of the stored values (raw or normalized).
struct VolumeStats {
  double min = 0, max = 0, mean = 0, stddev = 0;
  double p01 = 0, p50 = 0, p99 = 0, p999 = 0;  // 1st, 50th, 99th, 99.9th percentiles
  double nonzero_fraction = 0;                 // voxels != min
  double foreground_fraction = 0;              // voxels > min + fg_rel * (max - min)
};
// fg_rel: relative foreground threshold (0.2 is what ../shared/data/README.md uses).
[[nodiscard]] VolumeStats compute_stats(const Volume& volume, double fg_rel = 0.2);

enum class AspectMode { kPhysical, kShape };
[[nodiscard]] std::string_view to_string(AspectMode mode);

// Half-extents a of the world box [-a, a]^3: (X sx, Y sy, Z sz) / max(...) for
// kPhysical, (X, Y, Z) / max(X, Y, Z) for kShape (report Eq. 9).
[[nodiscard]] Eigen::Vector3d aspect_scales(int nx, int ny, int nz, const VoxelSpacing& spacing, AspectMode mode);

// The index <-> world map of a volume of shape (nx, ny, nz) with half-extents `aspect`.
// Continuous index (i, j, k) = (column, row, page); integer indices are voxel centres.
class WorldFrame {
 public:
  WorldFrame() = default;
  WorldFrame(int nx, int ny, int nz, const Eigen::Vector3d& aspect);

  // x = a_x (2 (i + 0.5) / X - 1), likewise y, z.
  [[nodiscard]] Eigen::Vector3d world_from_index(const Eigen::Vector3d& ijk) const {
    return (ijk.array() * scale_.array() + offset_.array()).matrix();
  }
  // i = (x / a_x + 1) X / 2 - 0.5, likewise j, k (not clamped).
  [[nodiscard]] Eigen::Vector3d index_from_world(const Eigen::Vector3d& p) const {
    return ((p - offset_).array() / scale_.array()).matrix();
  }
  // World size of one voxel along each axis: 2 a / N.
  [[nodiscard]] const Eigen::Vector3d& voxel_size() const { return scale_; }
  [[nodiscard]] const Eigen::Vector3d& aspect() const { return aspect_; }
  [[nodiscard]] const Eigen::Vector3i& shape() const { return shape_; }  // (X, Y, Z)
  [[nodiscard]] bool contains(const Eigen::Vector3d& p) const { return (p.array().abs() <= aspect_.array()).all(); }

 private:
  Eigen::Vector3i shape_{0, 0, 0};
  Eigen::Vector3d aspect_{1, 1, 1};
  Eigen::Vector3d scale_{1, 1, 1};   // 2 a / N
  Eigen::Vector3d offset_{0, 0, 0};  // a (1 / N - 1)
};

// CONVENTIONS trilinear sampling: 0 outside the box, else interpolation between
// voxel centres with the continuous index clamped to [0, N-1]. Reference
// implementation (double precision index math); the ray marchers specialise it.
[[nodiscard]] float sample_trilinear(const Volume& volume, const WorldFrame& frame, const Eigen::Vector3d& p_world);

}  // namespace hisnegs::io
