// SPDX-License-Identifier: Apache-2.0
// Writes the compact (.hgs) and hierarchy (.hgw) seeds of fuzz_ply, whose reader
// (load_checkpoint) tells the formats apart by their first bytes: made by the
// writers themselves, so every field starts valid (checksums included) and the
// mutations reach past them. Usage: make_model_seeds OUT_DIR.
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "gmf/core/compact_checkpoint.hpp"
#include "gmf/core/hierarchy.hpp"
#include "gmf/core/hierarchy_file.hpp"
#include "io/atomic_file.hpp"

int main(int argc, char** argv) {
  using namespace hisnegs;
  if (argc != 2) {
    std::fprintf(stderr, "usage: make_model_seeds OUT_DIR\n");
    return 2;
  }
  const std::filesystem::path out = argv[1];
  std::filesystem::create_directories(out);
  gmf::GaussianMixture m;
  for (int k = 0; k < 150; ++k) {  // a helix of Gaussians: clustered, anisotropic, varied intensities
    gmf::GaussianParams g;
    const double t = 0.1 * k;
    g.mean = {static_cast<float>(0.5 * std::cos(t)), static_cast<float>(0.5 * std::sin(t)),
              static_cast<float>(0.01 * k - 0.7)};
    g.log_scale = {-3.0f, -3.5f, static_cast<float>(-4.0 + 0.01 * k)};
    g.rotation = {1.0f, static_cast<float>(0.1 * std::sin(t)), 0.0f, static_cast<float>(0.1 * std::cos(t))};
    g.intensity_logit = static_cast<float>(std::sin(3 * t) * 2);
    m.push_back(g);
  }
  gmf::CheckpointMeta meta;
  meta.extra.emplace_back("source", "make_model_seeds");
  const std::string compact = gmf::encode_compact_checkpoint(m, meta);
  io::write_file_atomic(out / "seed_compact.hgs", compact.data(), compact.size());
  gmf::HierarchyOptions o;
  o.page = 64;
  const std::string hgw = gmf::encode_hierarchy_file(gmf::build_hierarchy(m, o), meta);
  io::write_file_atomic(out / "seed_hierarchy.hgw", hgw.data(), hgw.size());
  std::printf("make_model_seeds: %s: seed_compact.hgs (%zu B), seed_hierarchy.hgw (%zu B)\n", out.c_str(),
              compact.size(), hgw.size());
  return 0;
}
