// SPDX-License-Identifier: Apache-2.0
// estimate_background (foreground mask, its dilation by the guard, the histogram of
// what is left) and BackgroundModel's order statistics and text form.
#include "gmf/core/background.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <map>
#include <sstream>
#include <stdexcept>

#include "io/error.hpp"

namespace hisnegs::gmf {
namespace {

std::string shortest(double v) {
  char text[64];
  const auto result = std::to_chars(text, text + sizeof text, v);
  return std::string(text, result.ptr);
}

// Dilates a 0/1 mask by `r` voxels along one axis (a running max over 2r + 1).
void dilate_axis(std::vector<std::uint8_t>& mask, int nx, int ny, int nz, int axis, int r) {
  const int n[3] = {nx, ny, nz};
  const std::size_t stride[3] = {1, static_cast<std::size_t>(nx), static_cast<std::size_t>(nx) * ny};
  const int len = n[axis];
  std::vector<std::uint8_t> line(static_cast<std::size_t>(len)), out(static_cast<std::size_t>(len));
  const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
  for (int j = 0; j < n[a2]; ++j) {
    for (int i = 0; i < n[a1]; ++i) {
      const std::size_t base = static_cast<std::size_t>(i) * stride[a1] + static_cast<std::size_t>(j) * stride[a2];
      for (int t = 0; t < len; ++t) line[static_cast<std::size_t>(t)] = mask[base + t * stride[axis]];
      // Distance to the nearest set voxel, forwards and backwards.
      int last = -1'000'000;
      for (int t = 0; t < len; ++t) {
        if (line[static_cast<std::size_t>(t)]) last = t;
        out[static_cast<std::size_t>(t)] = t - last <= r ? 1 : 0;
      }
      last = 1'000'000;
      for (int t = len - 1; t >= 0; --t) {
        if (line[static_cast<std::size_t>(t)]) last = t;
        if (last - t <= r) out[static_cast<std::size_t>(t)] = 1;
      }
      for (int t = 0; t < len; ++t) mask[base + t * stride[axis]] = out[static_cast<std::size_t>(t)];
    }
  }
}

}  // namespace

void BackgroundOptions::validate() const {
  if (!(foreground_level > 0.0 && foreground_level < 1.0)) {
    throw io::InputError("background.foreground_level = " + io::number_text(foreground_level) + ": must be in (0, 1)");
  }
  if (guard_voxels < 0 || guard_voxels > 16) {
    throw io::InputError("background.guard_voxels = " + std::to_string(guard_voxels) + ": must be in [0, 16]");
  }
  if (max_atoms < 16 || max_atoms > 4096) {
    throw io::InputError("background.max_atoms = " + std::to_string(max_atoms) + ": must be in [16, 4096]");
  }
  if (!(subtracted_zero_fraction > 0.0 && subtracted_zero_fraction <= 1.0)) {
    throw io::InputError("background.subtracted_zero_fraction = " + io::number_text(subtracted_zero_fraction) +
                     ": must be in (0, 1]");
  }
  if (region_voxels != 0 && (region_voxels < 16 || region_voxels > 65536)) {
    throw io::InputError("background.region_voxels = " + std::to_string(region_voxels) +
                     ": must be 0 (one region) or in [16, 65536]");
  }
}

bool BackgroundModel::none() const { return values.empty() || values.back() <= 0.0; }

double BackgroundModel::expected_max(double n) const {
  if (none()) return 0.0;
  n = std::max(n, 1.0);
  double previous = 0.0, sum = 0.0;
  for (std::size_t i = 0; i < values.size(); ++i) {
    const double now = std::pow(cdf[i], n);
    sum += values[i] * (now - previous);
    previous = now;
  }
  return sum;
}

double BackgroundModel::mean() const { return expected_max(1.0); }

double BackgroundModel::quantile(double p) const {
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (cdf[i] >= p) return values[i];
  }
  return values.empty() ? 0.0 : values.back();
}

std::string BackgroundModel::text() const {
  std::string out = shortest(samples_per_voxel) + " " + std::to_string(values.size());
  for (std::size_t i = 0; i < values.size(); ++i) out += " " + shortest(values[i]) + " " + shortest(cdf[i]);
  return out;
}

void BackgroundModel::validate(const std::string& source) const {
  const auto fail = [&](const std::string& problem) { io::fail_input(source, "background: " + problem); };
  if (!(std::isfinite(samples_per_voxel) && samples_per_voxel > 0.0 && samples_per_voxel <= 1e3)) {
    fail("samples per voxel " + io::number_text(samples_per_voxel) + " is not in (0, 1000]");
  }
  if (values.size() != cdf.size()) fail("values and probabilities differ in number");
  if (values.size() > 4096) fail(std::to_string(values.size()) + " atoms, at most 4096");
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (!(std::isfinite(values[i]) && values[i] >= 0.0 && values[i] <= 1.0)) {
      fail("value " + io::number_text(values[i]) + " is not in [0, 1]");
    }
    if (!(cdf[i] > 0.0 && cdf[i] <= 1.0)) fail("probability " + io::number_text(cdf[i]) + " is not in (0, 1]");
    if (i > 0 && !(values[i] > values[i - 1] && cdf[i] > cdf[i - 1])) {
      fail("atom " + std::to_string(i) + " does not increase in value and probability");
    }
  }
  if (!values.empty() && cdf.back() != 1.0) fail("the last probability is " + io::number_text(cdf.back()) + ", not 1");
}

BackgroundModel BackgroundModel::parse(std::string_view text, const std::string& source) {
  std::istringstream in{std::string(text)};
  BackgroundModel m;
  std::size_t count = 0;
  if (!(in >> m.samples_per_voxel >> count) || count > 4096) {
    io::fail_input(source,
               "background: expected 'SAMPLES_PER_VOXEL N v_1 F_1 ... v_N F_N', got '" + io::printable(text, 60) + "'");
  }
  m.values.resize(count);
  m.cdf.resize(count);
  for (std::size_t i = 0; i < count; ++i) {
    if (!(in >> m.values[i] >> m.cdf[i])) {
      io::fail_input(source, "background: " + std::to_string(count) + " atoms declared, fewer given");
    }
  }
  std::string extra;
  if (in >> extra) io::fail_input(source, "background: more than the " + std::to_string(count) + " atoms declared");
  m.validate(source);
  return m;
}

void BackgroundCounts::add(float v, std::int64_t n) {
  total += n;
  zeros += v == 0.0f ? n : 0;
  if (!rounded && values.size() >= kMaxValues && !values.contains(v)) {
    rounded = true;  // too many distinct values: round everything counted so far, and from now on
    std::map<float, std::int64_t> old;
    old.swap(values);
    for (const auto& [value, count] : old) values[round(value)] += count;
  }
  values[rounded ? round(v) : v] += n;
}

float BackgroundCounts::round(float v) {
  const double step = 1.0 / static_cast<double>(kMaxValues);
  return static_cast<float>(std::round(static_cast<double>(v) / step) * step);
}

void BackgroundCounts::merge(const BackgroundCounts& other) {
  if (other.rounded && !rounded) {
    BackgroundCounts copy = other;
    copy.merge(*this);
    *this = std::move(copy);
    return;
  }
  for (const auto& [value, count] : other.values) add(value, count);
}

namespace {

// 1 where a voxel is foreground or within guard_voxels of it (not background).
std::vector<std::uint8_t> not_background(const io::Volume& volume, const BackgroundOptions& options) {
  const std::size_t n = volume.size();
  std::vector<std::uint8_t> mask(n);
  bool any = false;
  for (std::size_t i = 0; i < n; ++i) {
    mask[i] = volume.voxels[i] > options.foreground_level ? 1 : 0;
    any = any || mask[i] != 0;
  }
  if (options.guard_voxels > 0 && any) {  // (an empty brick of a large stack has nothing to dilate)
    for (int axis = 0; axis < 3; ++axis) dilate_axis(mask, volume.nx, volume.ny, volume.nz, axis, options.guard_voxels);
  }
  return mask;
}

void count_box(const io::Volume& volume, const std::vector<std::uint8_t>& mask, const io::VoxelBox& box,
               BackgroundCounts& counts) {
  for (int z = box.lo[2]; z < box.hi[2]; ++z) {
    for (int y = box.lo[1]; y < box.hi[1]; ++y) {
      for (int x = box.lo[0]; x < box.hi[0]; ++x) {
        const std::size_t i = volume.index(x, y, z);
        if (!mask[i]) counts.add(std::max(volume.voxels[i], 0.0f));
      }
    }
  }
}

}  // namespace

BackgroundCounts count_background(const io::Volume& volume, const BackgroundOptions& options, const io::VoxelBox& box) {
  options.validate();
  BackgroundCounts counts;
  count_box(volume, not_background(volume, options), box, counts);
  return counts;
}

BackgroundRegions BackgroundRegions::of(const std::array<int, 3>& shape, int region_voxels) {
  BackgroundRegions r;
  r.shape = shape;
  for (int a = 0; a < 3; ++a) {
    r.cells[a] = region_voxels <= 0 ? 1 : std::clamp((shape[a] + region_voxels - 1) / region_voxels, 1, kMaxPerAxis);
    r.cells[a] = std::min(r.cells[a], std::max(1, shape[a]));
  }
  return r;
}

io::VoxelBox BackgroundRegions::box(int region) const {
  const int k[3] = {region % cells[0], (region / cells[0]) % cells[1], region / (cells[0] * cells[1])};
  io::VoxelBox b;
  for (int a = 0; a < 3; ++a) {
    b.lo[a] = edge(a, k[a]);
    b.hi[a] = edge(a, k[a] + 1);
  }
  return b;
}

int BackgroundRegions::cell_of(int axis, int voxel) const {
  int k = static_cast<int>(static_cast<std::int64_t>(voxel) * cells[axis] / std::max(1, shape[axis]));
  k = std::clamp(k, 0, cells[axis] - 1);
  while (k > 0 && voxel < edge(axis, k)) --k;
  while (k + 1 < cells[axis] && voxel >= edge(axis, k + 1)) ++k;
  return k;
}

BackgroundField::Summary BackgroundField::summary() const {
  Summary s;
  for (const BackgroundModel& m : models) {
    s.subtracted += m.none() ? 1 : 0;
    s.merged += m == merged ? 1 : 0;
    if (m.none()) continue;
    s.p99_lo = std::min(s.p99_lo, m.quantile(0.99));
    s.p99_hi = std::max(s.p99_hi, m.quantile(0.99));
  }
  return s;
}

bool BackgroundField::none() const {
  if (!regional()) return merged.none();
  return std::all_of(models.begin(), models.end(), [](const BackgroundModel& m) { return m.none(); });
}

std::vector<BackgroundCounts> count_background_regions(const io::Volume& volume, const BackgroundOptions& options,
                                                       const io::VoxelBox& box, const BackgroundRegions& regions,
                                                       const std::array<int, 3>& origin) {
  options.validate();
  std::vector<BackgroundCounts> out(static_cast<std::size_t>(regions.count()));
  const std::vector<std::uint8_t> mask = not_background(volume, options);
  for (int r = 0; r < regions.count(); ++r) {
    const io::VoxelBox region = regions.box(r);
    io::VoxelBox part;  // the region in `volume`'s index space, clipped to `box`
    bool empty = false;
    for (int a = 0; a < 3; ++a) {
      part.lo[a] = std::max(box.lo[a], region.lo[a] - origin[a]);
      part.hi[a] = std::min(box.hi[a], region.hi[a] - origin[a]);
      empty = empty || part.hi[a] <= part.lo[a];
    }
    if (!empty) count_box(volume, mask, part, out[static_cast<std::size_t>(r)]);
  }
  return out;
}

BackgroundField background_field(const std::vector<BackgroundCounts>& counts, const BackgroundRegions& regions,
                                 const BackgroundOptions& options, const std::string& source) {
  if (counts.size() != static_cast<std::size_t>(regions.count())) {
    throw std::invalid_argument("background_field: " + std::to_string(counts.size()) + " counts for " +
                                std::to_string(regions.count()) + " regions");
  }
  BackgroundCounts all;
  for (const BackgroundCounts& c : counts) all.merge(c);
  BackgroundField field;
  field.regions = regions;
  field.merged = background_from_counts(all, options, source);
  if (regions.count() == 1) return field;
  for (const BackgroundCounts& c : counts) {
    field.models.push_back(c.total < BackgroundField::kMinVoxels ? field.merged
                                                                 : background_from_counts(c, options, source));
  }
  return field;
}

BackgroundField estimate_background_field(const io::Volume& volume, const BackgroundOptions& options) {
  const BackgroundRegions regions = BackgroundRegions::of({volume.nx, volume.ny, volume.nz}, options.region_voxels);
  const io::VoxelBox all{{0, 0, 0}, {volume.nx, volume.ny, volume.nz}};
  return background_field(count_background_regions(volume, options, all, regions, {0, 0, 0}), regions, options,
                          volume.source);
}

BackgroundModel background_from_counts(const BackgroundCounts& counts, const BackgroundOptions& options,
                                       const std::string& source) {
  options.validate();
  const std::int64_t total = counts.total;
  if (total == 0) {
    io::fail_input(source, "no background voxels (every voxel is within " + std::to_string(options.guard_voxels) +
                           " voxels of one above " + io::number_text(options.foreground_level) + ")");
  }
  BackgroundModel m;
  m.voxels = total;
  if (static_cast<double>(counts.zeros) >= options.subtracted_zero_fraction * static_cast<double>(total)) {
    m.values = {0.0};  // a subtracted background: none()
    m.cdf = {1.0};
    return m;
  }
  std::int64_t running = 0;
  if (counts.values.size() > static_cast<std::size_t>(options.max_atoms)) {
    // Too many distinct values: equal-width bins over [0, largest], each atom at its
    // bin's mean value (so the mean of the distribution is kept).
    const int bins = options.max_atoms;
    const double largest = counts.values.rbegin()->first;
    std::vector<double> sum(static_cast<std::size_t>(bins), 0.0);
    std::vector<std::int64_t> count(static_cast<std::size_t>(bins), 0);
    for (const auto& [value, c] : counts.values) {
      const int b = std::min(bins - 1, static_cast<int>(value / largest * bins));
      sum[static_cast<std::size_t>(b)] += static_cast<double>(value) * static_cast<double>(c);
      count[static_cast<std::size_t>(b)] += c;
    }
    for (int b = 0; b < bins; ++b) {
      if (count[static_cast<std::size_t>(b)] == 0) continue;
      running += count[static_cast<std::size_t>(b)];
      m.values.push_back(sum[static_cast<std::size_t>(b)] / static_cast<double>(count[static_cast<std::size_t>(b)]));
      m.cdf.push_back(static_cast<double>(running) / static_cast<double>(total));
    }
  } else {
    for (const auto& [value, c] : counts.values) {
      running += c;
      m.values.push_back(value);
      m.cdf.push_back(static_cast<double>(running) / static_cast<double>(total));
    }
  }
  m.cdf.back() = 1.0;
  return m;
}

BackgroundModel estimate_background(const io::Volume& volume, const BackgroundOptions& options) {
  const io::VoxelBox all{{0, 0, 0}, {volume.nx, volume.ny, volume.nz}};
  return background_from_counts(count_background(volume, options, all), options, volume.source);
}

}  // namespace hisnegs::gmf
