// SPDX-License-Identifier: Apache-2.0
// make_synthetic_neuron: grows a random neuron skeleton in µm, rasterizes it with an
// anti-aliased tube profile, blurs it with the rest of the PSF and simulates the camera.
// Owns no file format and no normalization (volume.cpp does that on the result).
#include "apps/simulate/synthetic_neuron.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <Eigen/Geometry>  // unitOrthogonal

#include <algorithm>
#include <cmath>
#include <deque>
#include <numbers>
#include <random>
#include <sstream>
#include <string>
#include <utility>

#include "io/config.hpp"
#include "io/error.hpp"
#include "io/hash.hpp"

namespace hisnegs::simulate {
namespace {

using Eigen::Vector3d;

// Morphology constants that shape the neuron but are not worth a knob.
constexpr double kTrunkWidening = 0.8;         // primary radius at the soma is (1 + this) x max_radius
constexpr double kTrunkLengthUm = 3.0;         // e-folding length of that widening
constexpr double kChildRadiusRatio = 0.75;     // fork: child radius / parent radius at the fork
constexpr double kParentRadiusRatio = 0.88;    // fork: parent radius after / before the fork
constexpr double kMinForkSpacingUm = 3.0;      // no fork closer than this to a neurite's start
constexpr double kBeadBrightening = 0.3;       // a mean bead is 30 % denser than its neurite
constexpr double kMaxNeuriteBrightness = 0.9;  // neurites stay dimmer than the soma (= 1)
constexpr double kSomaLobeOffset = 0.3;        // soma = sphere + 3 lobes at this x radius off-centre
constexpr double kSomaLobeRadius = 0.7;        // lobe radius / soma radius (lobes stay inside it)
constexpr double kProfileCutoff = 4.0;         // profiles are evaluated out to r + 4 sigma
constexpr double kMaxVoxels = 2147483648.0;    // 2^31: the volume must stay addressable

// Independent streams: the morphology and each z-slice's noise.
constexpr std::uint64_t kMorphologyStream = 0x6D6F7270686F6CULL;
constexpr std::uint64_t kNoiseStream = 0x6E6F697365ULL;
std::uint64_t stream_seed(std::uint64_t seed, std::uint64_t stream, std::uint64_t index) {
  return io::splitmix64(io::splitmix64(seed ^ stream) + index);
}

template <class T>
std::string to_text(const T& value) {
  std::ostringstream out;
  out << value;
  return out.str();
}

// "synth.FIELD = VALUE: RULE", as every options struct reports (config section `synth`).
[[noreturn]] void fail_field(const std::string& field, const std::string& value, const std::string& rule) {
  io::fail_option("synth", field, value, rule);
}

void require_range(const char* field, double value, double lo, double hi, bool lo_open = false) {
  const bool ok = std::isfinite(value) && (lo_open ? value > lo : value >= lo) && value <= hi;
  if (!ok) {
    fail_field(field, to_text(value),
               std::string("must be in ") + (lo_open ? "(" : "[") + to_text(lo) + ", " + to_text(hi) + "]");
  }
}

class Random {
 public:
  explicit Random(std::uint64_t seed) : engine_(seed) {}
  double uniform(double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(engine_); }
  double normal() { return normal_(engine_); }
  Vector3d normal3() {
    const double x = normal(), y = normal(), z = normal();
    return {x, y, z};
  }

 private:
  std::mt19937_64 engine_;
  std::normal_distribution<double> normal_{0.0, 1.0};
};

// ----------------------------------------------------------------------------------
// Morphology: persistent random walks in µm that fork, taper and bead.

struct NeuriteSeed {
  int parent_node = 0;  // skeleton node the neurite grows from
  Vector3d position;    // its first node
  Vector3d direction;   // unit
  double radius_start = 0;
  double path_from_soma_um = 0;
  int order = 0;  // 0 for primaries, +1 per fork
  double log_brightness = 0;
};

// A unit vector perpendicular to `d`, random, with its z part damped by `z_scale`.
Vector3d random_perpendicular(const Vector3d& d, double z_scale, Random& rng) {
  for (int attempt = 0; attempt < 16; ++attempt) {
    Vector3d u = rng.normal3();
    u.z() *= z_scale;
    u -= u.dot(d) * d;
    if (u.norm() > 1e-3) return u.normalized();
  }
  return d.unitOrthogonal();  // practically unreachable; any perpendicular will do
}

class SkeletonGrower {
 public:
  explicit SkeletonGrower(const SyntheticNeuronOptions& o) : o_(o), rng_(stream_seed(o.seed, kMorphologyStream, 0)) {
    for (int a = 0; a < 3; ++a) {
      const int n = a == 0 ? o.nx : a == 1 ? o.ny : o.nz;
      hi_[a] = (n - 1) * o.spacing_um[a] - o.margin_um;
      lo_[a] = o.margin_um;
    }
  }

  std::vector<NeuriteNode> grow() {
    place_soma();
    std::deque<NeuriteSeed> queue;
    const int n = o_.primary_branches;
    const double phi0 = rng_.uniform(0, 2 * std::numbers::pi);
    const double max_elevation = (1 - o_.planarity) * std::numbers::pi / 4;
    for (int i = 0; i < n; ++i) {
      const double phi = phi0 + 2 * std::numbers::pi * (i + rng_.uniform(-0.3, 0.3)) / n;
      const double elevation = rng_.uniform(-max_elevation, max_elevation);
      const Vector3d dir(std::cos(elevation) * std::cos(phi), std::cos(elevation) * std::sin(phi), std::sin(elevation));
      NeuriteSeed seed;
      seed.parent_node = 0;
      seed.position = soma_ + 0.8 * o_.soma_radius_um * dir;
      seed.direction = dir;
      seed.radius_start = o_.max_radius_um;
      seed.path_from_soma_um = 0.8 * o_.soma_radius_um;
      seed.log_brightness = o_.brightness_variation * rng_.normal();
      queue.push_back(seed);
    }
    started_ = n;
    // Breadth first, so that max_branches trims the finest forks, not whole primaries.
    while (!queue.empty()) {
      const NeuriteSeed seed = queue.front();
      queue.pop_front();
      grow_neurite(seed, queue);
    }
    return std::move(nodes_);
  }

  const std::vector<Vector3d>& soma_lobes() const { return lobes_; }

 private:
  bool inside(const Vector3d& p) const {
    for (int a = 0; a < 3; ++a) {
      if (p[a] < lo_[a] || p[a] > hi_[a]) return false;
    }
    return true;
  }

  void place_soma() {
    // Near the centre, jittered, and fully inside the margins (validate() made room).
    const double jitter[3] = {0.12, 0.12, 0.05};
    for (int a = 0; a < 3; ++a) {
      const double centre = 0.5 * (lo_[a] + hi_[a]);
      const double half = 0.5 * (hi_[a] - lo_[a]);
      const double p = centre + jitter[a] * half * 2 * rng_.uniform(-1, 1);
      soma_[a] = std::clamp(p, lo_[a] + o_.soma_radius_um, hi_[a] - o_.soma_radius_um);
    }
    nodes_.push_back({soma_, o_.soma_radius_um, -1, 1.0});
    for (int k = 0; k < 3; ++k) {
      Vector3d u = rng_.normal3();
      u.z() *= 0.5;  // somata are flatter along the optical axis in most preparations
      lobes_.push_back(soma_ + kSomaLobeOffset * o_.soma_radius_um * u.normalized());
    }
  }

  // Bead profile near path position s: sum of Gaussian bumps of height U(0.4, 1.6)
  // (mean 1) centred every ~varicosity_period_um (beads generated lazily along s).
  struct Beads {
    std::deque<std::pair<double, double>> centre_amplitude;
    double last_centre = 0;
  };
  double bead_bump(Beads& beads, double s) {
    const double w = o_.varicosity_length_um;
    while (beads.last_centre < s + kProfileCutoff * w) {
      beads.last_centre += o_.varicosity_period_um * rng_.uniform(0.5, 1.5);
      beads.centre_amplitude.emplace_back(beads.last_centre, rng_.uniform(0.4, 1.6));
    }
    while (!beads.centre_amplitude.empty() && beads.centre_amplitude.front().first < s - kProfileCutoff * w) {
      beads.centre_amplitude.pop_front();
    }
    double bump = 0;
    for (const auto& [c, a] : beads.centre_amplitude) {
      const double t = (s - c) / w;
      bump += a * std::exp(-0.5 * t * t);
    }
    return bump;
  }

  void grow_neurite(const NeuriteSeed& seed, std::deque<NeuriteSeed>& queue) {
    if (!inside(seed.position)) return;
    const double z_scale = 1 - o_.planarity;
    const double step = o_.step_um;
    Vector3d pos = seed.position;
    Vector3d dir = seed.direction;
    int previous = seed.parent_node;
    double s_local = 0;
    double path = seed.path_from_soma_um;
    double log_b = seed.log_brightness;
    double radius_start = seed.radius_start;
    Beads beads;
    beads.last_centre = o_.varicosity_period_um * rng_.uniform(-0.5, 0.5);
    // Ornstein-Uhlenbeck log-brightness with correlation length L: exact update per step.
    const double decay = std::exp(-step / o_.brightness_correlation_um);
    const double kick = o_.brightness_variation * std::sqrt(1 - decay * decay);
    while (true) {
      double r_base = o_.min_radius_um + (radius_start - o_.min_radius_um) * std::exp(-s_local / o_.taper_length_um);
      if (seed.order == 0) r_base *= 1 + kTrunkWidening * std::exp(-s_local / kTrunkLengthUm);
      const double bump = bead_bump(beads, s_local);
      const double brightness =
          std::min(kMaxNeuriteBrightness, o_.neurite_brightness * std::exp(log_b) * (1 + kBeadBrightening * bump));
      nodes_.push_back({pos, r_base + o_.varicosity_radius_um * bump, previous, brightness});
      previous = static_cast<int>(nodes_.size()) - 1;

      if (seed.order < o_.max_branch_order && started_ < o_.max_branches && s_local >= kMinForkSpacingUm &&
          rng_.uniform(0, 1) < o_.branch_probability_per_um * step) {
        const double angle = rng_.uniform(25, 65) * std::numbers::pi / 180;
        const Vector3d u = random_perpendicular(dir, z_scale, rng_);
        const Vector3d child_dir = (std::cos(angle) * dir + std::sin(angle) * u).normalized();
        NeuriteSeed child;
        child.parent_node = previous;
        child.position = pos + step * child_dir;
        child.direction = child_dir;
        child.radius_start = std::max(o_.min_radius_um, kChildRadiusRatio * r_base);
        child.path_from_soma_um = path + step;
        child.order = seed.order + 1;
        child.log_brightness = log_b;
        queue.push_back(child);
        ++started_;
        // The parent swerves a little away from its child and thins.
        dir = (dir - 0.3 * std::sin(angle) * u).normalized();
        radius_start = o_.min_radius_um + kParentRadiusRatio * (radius_start - o_.min_radius_um);
      }

      // Persistent random walk: small random turns, a pull away from the soma, z damped.
      Vector3d turn = rng_.normal3() * (o_.tortuosity * std::sqrt(step));
      turn.z() *= z_scale;
      Vector3d away = pos - soma_;
      away.z() *= z_scale;
      if (away.norm() > 1e-9) away.normalize();
      dir = (dir + turn + o_.outward_bias * step * away).normalized();
      const Vector3d next = pos + step * dir;
      if (!inside(next) || path + step > o_.max_path_length_um) break;
      pos = next;
      path += step;
      s_local += step;
      log_b = decay * log_b + kick * rng_.normal();
    }
  }

  const SyntheticNeuronOptions& o_;
  Random rng_;
  double lo_[3] = {0, 0, 0}, hi_[3] = {0, 0, 0};
  Vector3d soma_{0, 0, 0};
  std::vector<Vector3d> lobes_;
  std::vector<NeuriteNode> nodes_;
  int started_ = 0;
};

// ----------------------------------------------------------------------------------
// Rasterization: each primitive is a tapered capsule (p0, r0, b0) -> (p1, r1, b1); a
// sphere is a capsule of length 0. Its value at x, at offset delta (length rho) from the
// nearest axis point, is b * slab(rho; r, sigma) with
//   slab = 0.5 [erf((r - rho) / (sqrt2 sigma)) + erf((r + rho) / (sqrt2 sigma))],
// the exact profile of a slab of half-width r blurred by a Gaussian of std dev sigma,
// taken along delta with sigma^2 = delta^T Sigma_aa delta / rho^2 (the anti-aliasing
// part of the PSF in that direction). It is flat-topped for r >> sigma and dims
// thin neurites (peak ~ 0.8 r / sigma) as a real confocal does. Primitives combine
// with max (overlaps do not add up).

struct Primitive {
  Vector3d p0, p1;
  double r0 = 0, r1 = 0, b0 = 0, b1 = 0;
  int lo[3] = {0, 0, 0}, hi[3] = {-1, -1, -1};  // voxel bounding box, inclusive
};

struct Grid {
  int n[3];
  double s[3];
};

Primitive make_primitive(const Vector3d& p0, double r0, double b0, const Vector3d& p1, double r1, double b1,
                         const Grid& g, const double sigma_aa[3]) {
  Primitive p{p0, p1, r0, r1, b0, b1};
  const double r = std::max(r0, r1);
  for (int a = 0; a < 3; ++a) {
    const double reach = r + kProfileCutoff * sigma_aa[a];
    const double lo_um = std::min(p0[a], p1[a]) - reach;
    const double hi_um = std::max(p0[a], p1[a]) + reach;
    p.lo[a] = std::max(0, static_cast<int>(std::ceil(lo_um / g.s[a])));
    p.hi[a] = std::min(g.n[a] - 1, static_cast<int>(std::floor(hi_um / g.s[a])));
  }
  return p;
}

void rasterize_slice(const std::vector<Primitive>& prims, const std::vector<int>& ids, int k, const Grid& g,
                     const double sigma_aa[3], float* slice) {
  const double var[3] = {sigma_aa[0] * sigma_aa[0], sigma_aa[1] * sigma_aa[1], sigma_aa[2] * sigma_aa[2]};
  const double var_max = std::max({var[0], var[1], var[2]});
  const double var_mean = (var[0] + var[1] + var[2]) / 3;
  const double z = k * g.s[2];
  for (const int id : ids) {
    const Primitive& p = prims[id];
    const Vector3d axis = p.p1 - p.p0;
    const double axis2 = axis.squaredNorm();
    const double r_max = std::max(p.r0, p.r1);
    const double reach = r_max + kProfileCutoff * std::sqrt(var_max);
    const double reach2 = reach * reach;
    for (int j = p.lo[1]; j <= p.hi[1]; ++j) {
      const double y = j * g.s[1];
      float* row = slice + static_cast<std::size_t>(j) * g.n[0];
      for (int i = p.lo[0]; i <= p.hi[0]; ++i) {
        const Vector3d x(i * g.s[0], y, z);
        const Vector3d d = x - p.p0;
        const double t = axis2 > 0 ? std::clamp(d.dot(axis) / axis2, 0.0, 1.0) : 0.0;
        const Vector3d delta = d - t * axis;
        const double rho2 = delta.squaredNorm();
        if (rho2 > reach2) continue;
        const double b = p.b0 + t * (p.b1 - p.b0);
        if (row[i] >= b) continue;  // max-combine: cannot raise this voxel
        const double r = p.r0 + t * (p.r1 - p.r0);
        const double sigma2 =
            rho2 > 1e-24
                ? (delta.x() * delta.x() * var[0] + delta.y() * delta.y() * var[1] + delta.z() * delta.z() * var[2]) /
                      rho2
                : var_mean;
        const double rho = std::sqrt(rho2);
        double slab;
        if (sigma2 > 0) {
          const double inv = 1 / std::sqrt(2 * sigma2);
          slab = 0.5 * (std::erf((r - rho) * inv) + std::erf((r + rho) * inv));
        } else {
          slab = rho <= r ? 1.0 : 0.0;
        }
        row[i] = std::max(row[i], static_cast<float>(b * slab));
      }
    }
  }
}

// ----------------------------------------------------------------------------------
// Separable Gaussian blur with zero padding, one axis at a time, in place.

std::vector<float> gaussian_kernel(double sigma_vox) {
  const int radius = std::max(1, static_cast<int>(std::ceil(kProfileCutoff * sigma_vox)));
  std::vector<float> w(2 * radius + 1);
  double sum = 0;
  for (int k = -radius; k <= radius; ++k) {
    const double v = std::exp(-0.5 * k * k / (sigma_vox * sigma_vox));
    w[k + radius] = static_cast<float>(v);
    sum += v;
  }
  for (float& v : w) v = static_cast<float>(v / sum);
  return w;
}

// Convolves `count` lines of length `len` (element m of line l at base(l) + m * stride).
// Lines are independent, so any parallel split gives the same result.
template <class Base>
void blur_lines(float* data, int count, int len, std::size_t stride, Base base, const std::vector<float>& w) {
  const int radius = static_cast<int>(w.size() / 2);
  tbb::parallel_for(tbb::blocked_range<int>(0, count), [&](const tbb::blocked_range<int>& range) {
    std::vector<float> line(len);
    for (int l = range.begin(); l != range.end(); ++l) {
      float* p = data + base(l);
      for (int m = 0; m < len; ++m) line[m] = p[m * stride];
      for (int m = 0; m < len; ++m) {
        const int k0 = std::max(-radius, -m), k1 = std::min(radius, len - 1 - m);
        float acc = 0;
        for (int k = k0; k <= k1; ++k) acc += w[k + radius] * line[m + k];
        p[m * stride] = acc;
      }
    }
  });
}

void blur(std::vector<float>& v, const Grid& g, const double sigma_vox[3]) {
  const std::size_t nx = g.n[0], ny = g.n[1];
  if (sigma_vox[0] > 0) {
    blur_lines(
        v.data(), g.n[1] * g.n[2], g.n[0], 1, [&](int l) { return l * nx; }, gaussian_kernel(sigma_vox[0]));
  }
  if (sigma_vox[1] > 0) {
    blur_lines(
        v.data(), g.n[0] * g.n[2], g.n[1], nx, [&](int l) { return (l / nx) * nx * ny + l % nx; },
        gaussian_kernel(sigma_vox[1]));
  }
  if (sigma_vox[2] > 0) {
    blur_lines(
        v.data(), g.n[0] * g.n[1], g.n[2], nx * ny, [&](int l) { return static_cast<std::size_t>(l); },
        gaussian_kernel(sigma_vox[2]));
  }
}

}  // namespace

// ----------------------------------------------------------------------------------

void SyntheticNeuronOptions::validate() const {
  const char* dims[3] = {"nx", "ny", "nz"};
  const int n[3] = {nx, ny, nz};
  for (int a = 0; a < 3; ++a) {
    if (n[a] < 8 || n[a] > 4096) fail_field(dims[a], to_text(n[a]), "must be in [8, 4096]");
  }
  if (static_cast<double>(nx) * ny * nz > kMaxVoxels) {
    fail_field("nx*ny*nz", to_text(static_cast<double>(nx) * ny * nz), "must be at most 2^31 voxels");
  }
  for (int a = 0; a < 3; ++a) {
    const double s = spacing_um[a];
    if (!(std::isfinite(s) && s > 0 && s <= 100)) {
      fail_field("spacing_um[" + to_text(a) + "]", to_text(s), "must be in (0, 100] µm");
    }
  }
  if (primary_branches < 1 || primary_branches > 16) {
    fail_field("primary_branches", to_text(primary_branches), "must be in [1, 16]");
  }
  require_range("soma_radius_um", soma_radius_um, 0, 50, true);
  require_range("min_radius_um", min_radius_um, 0, 10, true);
  require_range("max_radius_um", max_radius_um, 0, 10, true);
  if (min_radius_um > max_radius_um) {
    fail_field("min_radius_um", to_text(min_radius_um), "must not exceed max_radius_um = " + to_text(max_radius_um));
  }
  require_range("taper_length_um", taper_length_um, 0, 1e4, true);
  require_range("branch_probability_per_um", branch_probability_per_um, 0, 1);
  if (max_branch_order < 0 || max_branch_order > 8) {
    fail_field("max_branch_order", to_text(max_branch_order), "must be in [0, 8]");
  }
  if (max_branches < primary_branches || max_branches > 1024) {
    fail_field("max_branches", to_text(max_branches),
               "must be in [primary_branches = " + to_text(primary_branches) + ", 1024]");
  }
  require_range("max_path_length_um", max_path_length_um, 0, 1e5, true);
  require_range("step_um", step_um, 0.05, 5);
  require_range("tortuosity", tortuosity, 0, 2);
  require_range("outward_bias", outward_bias, 0, 1);
  require_range("planarity", planarity, 0, 1);
  require_range("margin_um", margin_um, 0, 1e4);
  require_range("varicosity_period_um", varicosity_period_um, 0, 1e4, true);
  require_range("varicosity_radius_um", varicosity_radius_um, 0, 10);
  require_range("varicosity_length_um", varicosity_length_um, 0, 100, true);
  require_range("neurite_brightness", neurite_brightness, 0, kMaxNeuriteBrightness, true);
  require_range("brightness_variation", brightness_variation, 0, 3);
  require_range("brightness_correlation_um", brightness_correlation_um, 0, 1e4, true);
  require_range("psf_sigma_xy_um", psf_sigma_xy_um, 0, 100);
  require_range("psf_sigma_z_um", psf_sigma_z_um, 0, 100);
  require_range("peak_photons", peak_photons, 0, 1e5, true);
  require_range("background_photons", background_photons, 0, 1e4);
  require_range("gain_counts_per_photon", gain_counts_per_photon, 0, 100, true);
  require_range("read_noise", read_noise, 0, 1e4);
  require_range("camera_offset", camera_offset, 0, 60000);
  require_range("background_subtract_sigmas", background_subtract_sigmas, 0, 100);
  // The soma (with the margins) has to fit in the box along every axis.
  for (int a = 0; a < 3; ++a) {
    const double extent = (n[a] - 1) * spacing_um[a];
    if (2 * (soma_radius_um + margin_um) > extent) {
      fail_field("soma_radius_um", to_text(soma_radius_um),
                 "soma diameter + 2 margin_um (" + to_text(2 * (soma_radius_um + margin_um)) +
                     " µm) must fit the stack's " + "xyz"[a] + " extent of " + to_text(extent) + " µm");
    }
  }
}

namespace {

// Blur budget per axis: PSF plus the voxel's own box integration (s^2 / 12).
// Rasterization carries up to half a voxel of it (enough to sample sub-voxel
// neurites without aliasing, sigma_aa in µm), the separable convolution the rest
// (sigma_blur_vox, in voxels).
void split_blur(const SyntheticNeuronOptions& o, const Grid& g, double sigma_aa[3], double sigma_blur_vox[3]) {
  for (int a = 0; a < 3; ++a) {
    const double psf = a == 2 ? o.psf_sigma_z_um : o.psf_sigma_xy_um;
    const double total2 = psf * psf + g.s[a] * g.s[a] / 12;
    sigma_aa[a] = std::min(std::sqrt(total2), 0.5 * g.s[a]);
    sigma_blur_vox[a] = std::sqrt(std::max(0.0, total2 - sigma_aa[a] * sigma_aa[a])) / g.s[a];
    if (sigma_blur_vox[a] < 0.05) sigma_blur_vox[a] = 0;  // kernel would be a delta
  }
}

// Soma (sphere + lobes) and one tapered capsule per skeleton edge.
std::vector<Primitive> make_primitives(const std::vector<NeuriteNode>& nodes, const std::vector<Vector3d>& lobes,
                                       const Grid& g, const double sigma_aa[3]) {
  std::vector<Primitive> prims;
  const NeuriteNode& soma = nodes[0];
  prims.push_back(
      make_primitive(soma.position_um, soma.radius_um, 1.0, soma.position_um, soma.radius_um, 1.0, g, sigma_aa));
  for (const Vector3d& c : lobes) {
    const double r = kSomaLobeRadius * soma.radius_um;
    prims.push_back(make_primitive(c, r, 1.0, c, r, 1.0, g, sigma_aa));
  }
  for (std::size_t i = 1; i < nodes.size(); ++i) {
    const NeuriteNode& a = nodes[nodes[i].parent];
    const NeuriteNode& b = nodes[i];
    // Inside the soma the edge from its centre tapers from the first node's radius
    // (a soma-radius cone would bulge out of the soma).
    const double ra = nodes[i].parent == 0 ? b.radius_um : a.radius_um;
    const double ba = nodes[i].parent == 0 ? 1.0 : a.brightness;
    prims.push_back(make_primitive(a.position_um, ra, ba, b.position_um, b.radius_um, b.brightness, g, sigma_aa));
  }
  return prims;
}

// Rasterize (slices are independent) and blur: intensity in [0, 1], soma = 1.
std::vector<float> render_intensity(const std::vector<Primitive>& prims, const Grid& g, const double sigma_aa[3],
                                    const double sigma_blur_vox[3]) {
  const int nz = g.n[2];
  std::vector<std::vector<int>> by_slice(nz);
  for (int id = 0; id < static_cast<int>(prims.size()); ++id) {
    for (int k = prims[id].lo[2]; k <= prims[id].hi[2]; ++k) by_slice[k].push_back(id);
  }
  const std::size_t slice_size = static_cast<std::size_t>(g.n[0]) * g.n[1];
  std::vector<float> intensity(slice_size * nz, 0.0f);
  tbb::parallel_for(
      0, nz, [&](int k) { rasterize_slice(prims, by_slice[k], k, g, sigma_aa, intensity.data() + k * slice_size); });
  blur(intensity, g, sigma_blur_vox);
  return intensity;
}

// Camera: counts = gain Poisson(peak I + background) + Normal(0, read) + offset,
// rounded, clipped to [0, 65535]; then the background subtraction. One random
// stream per z-slice, so the result is independent of the thread schedule.
SyntheticNeuronCounts apply_camera(const SyntheticNeuronOptions& o, std::vector<float>& intensity) {
  const std::size_t slice_size = static_cast<std::size_t>(o.nx) * o.ny;
  const double threshold =
      o.background_subtract ? std::round(o.camera_offset + o.background_subtract_sigmas * o.read_noise) : 0.0;
  std::vector<std::int64_t> clipped_zero(o.nz, 0), saturated(o.nz, 0);
  tbb::parallel_for(0, o.nz, [&](int k) {
    std::mt19937_64 engine(stream_seed(o.seed, kNoiseStream, static_cast<std::uint64_t>(k)));
    std::normal_distribution<double> read(0.0, 1.0);
    std::poisson_distribution<std::int64_t> background_shot(std::max(o.background_photons, 1e-12));
    float* slice = intensity.data() + k * slice_size;
    for (std::size_t v = 0; v < slice_size; ++v) {
      const double signal = o.peak_photons * std::max(0.0f, slice[v]);
      std::int64_t photons;
      if (signal <= 0) {
        photons = o.background_photons > 0 ? background_shot(engine) : 0;
      } else {
        std::poisson_distribution<std::int64_t> shot(signal + o.background_photons);
        photons = shot(engine);
      }
      double raw = std::round(o.gain_counts_per_photon * static_cast<double>(photons) + o.read_noise * read(engine) +
                              o.camera_offset);
      if (raw < 0 || raw > 65535) {
        ++saturated[k];
        raw = std::clamp(raw, 0.0, 65535.0);
      }
      if (o.background_subtract) {
        if (raw < threshold) ++clipped_zero[k];
        raw = std::max(0.0, raw - threshold);
      }
      slice[v] = static_cast<float>(raw);
    }
  });
  SyntheticNeuronCounts counts;
  for (int k = 0; k < o.nz; ++k) {
    counts.clipped_to_zero += clipped_zero[k];
    counts.saturated += saturated[k];
  }
  return counts;
}

}  // namespace

io::Volume make_synthetic_neuron(const SyntheticNeuronOptions& options, std::vector<NeuriteNode>* skeleton,
                             SyntheticNeuronCounts* counts) {
  options.validate();
  const SyntheticNeuronOptions& o = options;
  const Grid g{{o.nx, o.ny, o.nz}, {o.spacing_um[0], o.spacing_um[1], o.spacing_um[2]}};
  SkeletonGrower grower(o);
  std::vector<NeuriteNode> nodes = grower.grow();
  double sigma_aa[3], sigma_blur_vox[3];
  split_blur(o, g, sigma_aa, sigma_blur_vox);
  std::vector<float> intensity =
      render_intensity(make_primitives(nodes, grower.soma_lobes(), g, sigma_aa), g, sigma_aa, sigma_blur_vox);
  const SyntheticNeuronCounts camera = apply_camera(o, intensity);

  io::Volume volume;
  volume.nx = o.nx;
  volume.ny = o.ny;
  volume.nz = o.nz;
  volume.voxels = std::move(intensity);
  volume.stored_as = io::SampleType::kUint16;
  volume.spacing.um = o.spacing_um;
  volume.spacing.source = {io::SpacingSource::kUser, io::SpacingSource::kUser, io::SpacingSource::kUser};
  volume.normalization = io::Normalization{};
  volume.source = "synthetic (seed " + to_text(o.seed) + ")";
  if (counts != nullptr) *counts = camera;
  if (skeleton != nullptr) *skeleton = std::move(nodes);
  return volume;
}

}  // namespace hisnegs::simulate
