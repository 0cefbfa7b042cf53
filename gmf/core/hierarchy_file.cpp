// SPDX-License-Identifier: Apache-2.0
// The `.hgw` hierarchy file: head, JSON index, CRC-32 of both, then the pages.
#include "gmf/core/hierarchy_file.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>
#include <tbb/parallel_for.h>

#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/json_depth.hpp"

namespace hisnegs::gmf {
namespace {

constexpr std::uint64_t kMostIndexBytes = std::uint64_t{64} << 20;  // ~300,000 nodes: 10^9 Gaussians in pages of 4096
constexpr std::size_t kMostNodes = std::size_t{1} << 24;
constexpr std::uint64_t kMostPageGaussians = 1000000;  // HierarchyOptions::page's bound

template <class T>
void put(std::string& out, T value) {
  char b[sizeof(T)];
  std::memcpy(b, &value, sizeof(T));  // little-endian hosts only (as the compact format)
  out.append(b, sizeof(T));
}

template <class T>
T get(std::string_view bytes, std::size_t at) {
  T value;
  std::memcpy(&value, bytes.data() + at, sizeof(T));
  return value;
}

[[noreturn]] void fail(const std::filesystem::path& source, const std::string& problem) {
  io::fail_input(source.string(), "hierarchy: " + problem);
}

nlohmann::json node_json(const HierarchyNode& n, std::uint64_t offset, std::uint64_t bytes) {
  nlohmann::json children = nlohmann::json::array();
  for (const std::int32_t c : n.children) children.push_back(c);
  return {{"lo", n.lo}, {"hi", n.hi},         {"level", n.level},   {"count", n.count},
          {"feature", n.feature}, {"offset", offset}, {"bytes", bytes}, {"children", children}};
}

// A number of `j` within [lo, hi]; fails naming node `i` and `what`.
double number(const nlohmann::json& j, const std::string& what, double lo, double hi, std::size_t i,
              const std::filesystem::path& source) {
  if (!j.is_number() || !std::isfinite(j.get<double>()) || j.get<double>() < lo || j.get<double>() > hi) {
    fail(source, "node " + std::to_string(i) + ": " + what + " missing, not a number or out of range");
  }
  return j.get<double>();
}

const nlohmann::json& field(const nlohmann::json& j, const char* name, std::size_t i,
                            const std::filesystem::path& source) {
  static const nlohmann::json none;
  if (!j.is_object()) fail(source, "node " + std::to_string(i) + " is not an object");
  const auto it = j.find(name);
  return it == j.end() ? none : *it;
}

// Node `i` of `nodes` (children after their parent, so no cycle), its page range
// appended to `index`.
HierarchyNode parse_node(const nlohmann::json& j, std::size_t i, std::size_t nodes, std::uint64_t file_bytes,
                         HierarchyIndex& index, const std::filesystem::path& source) {
  HierarchyNode n;
  for (const char* name : {"lo", "hi"}) {
    const nlohmann::json& box = field(j, name, i, source);
    if (!box.is_array() || box.size() != 3) fail(source, "node " + std::to_string(i) + ": " + name + " is not 3 numbers");
    for (std::size_t a = 0; a < 3; ++a) {
      (name[0] == 'l' ? n.lo : n.hi)[a] = number(box[a], name, -1e30, 1e30, i, source);
    }
  }
  n.level = static_cast<int>(number(field(j, "level", i, source), "level", 0, 64, i, source));
  n.count = static_cast<std::size_t>(
      number(field(j, "count", i, source), "count", 1, static_cast<double>(kMostPageGaussians), i, source));
  n.feature = number(field(j, "feature", i, source), "feature", 0, 1e30, i, source);
  const auto offset = static_cast<std::uint64_t>(
      number(field(j, "offset", i, source), "offset", static_cast<double>(index.index_end),
             static_cast<double>(file_bytes), i, source));
  const auto bytes = static_cast<std::uint64_t>(
      number(field(j, "bytes", i, source), "bytes", 1, static_cast<double>(file_bytes - offset), i, source));
  const nlohmann::json& children = field(j, "children", i, source);
  if (!children.is_array() || children.size() != 8) fail(source, "node " + std::to_string(i) + ": children is not 8 numbers");
  for (std::size_t c = 0; c < 8; ++c) {
    const double v = number(children[c], "child", -1, static_cast<double>(nodes) - 1, i, source);
    if (v >= 0 && v <= static_cast<double>(i)) fail(source, "node " + std::to_string(i) + ": a child before its parent");
    n.children[c] = static_cast<std::int32_t>(v);
  }
  index.offset.push_back(offset);
  index.bytes.push_back(bytes);
  return n;
}

}  // namespace

std::string encode_hierarchy_file(const Hierarchy& h, const CheckpointMeta& meta, const CompactOptions& options) {
  // Positions as fine as a whole-model .hgs of `options` would hold them (a step of
  // the root cell over 2^position_bits), in as few bits as each page's smaller box
  // needs. Pages are encoded in parallel (zstd at level 19 is most of the time).
  const double step =
      h.nodes.empty() ? 1.0 : (h.nodes[0].hi[0] - h.nodes[0].lo[0]) / std::ldexp(1.0, options.position_bits);
  std::vector<std::string> pages(h.nodes.size());
  tbb::parallel_for(std::size_t{0}, h.nodes.size(), [&](std::size_t i) {
    const HierarchyNode& n = h.nodes[i];
    GaussianMixture page;
    page.reserve(n.count);
    double extent = 0.0;
    std::array<float, 3> lo{1e30f, 1e30f, 1e30f}, hi{-1e30f, -1e30f, -1e30f};
    for (std::size_t k = n.first; k < n.first + n.count; ++k) {
      const GaussianParams& g = h.gaussians[k];
      for (std::size_t a = 0; a < 3; ++a) {
        lo[a] = std::min(lo[a], g.mean[a]);
        hi[a] = std::max(hi[a], g.mean[a]);
      }
      page.push_back(g);
    }
    for (std::size_t a = 0; a < 3; ++a) extent = std::max(extent, static_cast<double>(hi[a]) - lo[a]);
    CompactOptions own = options;
    own.position_bits = std::clamp(static_cast<int>(std::ceil(std::log2(std::max(extent, step) / step))), 8,
                                   options.position_bits);
    pages[i] = encode_compact_checkpoint(page, i == 0 ? meta : CheckpointMeta{}, own);
  });
  // The index's size depends on the offsets it holds: laid out twice (the second
  // time with the first's size, which only grows the offsets' digits as it must).
  std::string index_text;
  std::uint64_t start = 0;
  for (int pass = 0; pass < 8; ++pass) {
    nlohmann::json nodes = nlohmann::json::array();
    std::uint64_t at = kHierarchyHeadBytes + index_text.size() + 4;
    start = at;
    for (std::size_t i = 0; i < h.nodes.size(); ++i) {
      nodes.push_back(node_json(h.nodes[i], at, pages[i].size()));
      at += pages[i].size();
    }
    const nlohmann::json index = {{"format", "hisnegs hierarchy"}, {"version", kHierarchyFormatVersion},
                                  {"gaussians", h.model_gaussians}, {"nodes", nodes}};
    std::string text = index.dump();
    const bool settled = text.size() == index_text.size();  // the offsets above counted this size
    index_text = std::move(text);
    if (settled) break;
  }
  std::string out(kHierarchyMagic.data(), kHierarchyMagic.size());
  put<std::uint32_t>(out, kHierarchyFormatVersion);
  put<std::uint32_t>(out, 0);
  put<std::uint64_t>(out, index_text.size());
  out += index_text;
  put<std::uint32_t>(out, crc32_of(out));
  if (out.size() != start) throw std::logic_error("encode_hierarchy_file: the index did not settle");
  for (const std::string& p : pages) out += p;
  return out;
}

std::uint64_t save_hierarchy_file(const std::filesystem::path& path, const Hierarchy& h, const CheckpointMeta& meta,
                                  const CompactOptions& options) {
  const std::string bytes = encode_hierarchy_file(h, meta, options);
  io::write_file_atomic(path, bytes.data(), bytes.size());
  return bytes.size();
}

bool has_hierarchy_magic(std::string_view bytes) {
  return bytes.size() >= kHierarchyMagic.size() &&
         std::memcmp(bytes.data(), kHierarchyMagic.data(), kHierarchyMagic.size()) == 0;
}

HierarchyIndex read_hierarchy_index(std::string_view head, std::uint64_t file_bytes,
                                    const std::filesystem::path& source) {
  if (head.size() < kHierarchyHeadBytes || !has_hierarchy_magic(head)) fail(source, "not a hierarchy file (magic)");
  if (get<std::uint32_t>(head, 8) != kHierarchyFormatVersion) {
    fail(source, "version " + std::to_string(get<std::uint32_t>(head, 8)) + " (this build reads " +
                     std::to_string(kHierarchyFormatVersion) + ")");
  }
  const auto index_bytes = get<std::uint64_t>(head, 16);
  if (index_bytes > kMostIndexBytes || kHierarchyHeadBytes + index_bytes + 4 > file_bytes) {
    fail(source, "an index of " + std::to_string(index_bytes) + " bytes does not fit the file");
  }
  HierarchyIndex index;
  index.index_end = kHierarchyHeadBytes + index_bytes + 4;
  if (head.size() < index.index_end) fail(source, "truncated before the end of its index");
  if (crc32_of(head.substr(0, index.index_end - 4)) != get<std::uint32_t>(head, index.index_end - 4)) {
    fail(source, "the index fails its CRC-32 (damaged)");
  }
  const std::string_view text = head.substr(kHierarchyHeadBytes, index_bytes);
  if (!io::json_nests_within(text, 8)) fail(source, "the index nests deeper than a hierarchy's JSON");
  const nlohmann::json j = nlohmann::json::parse(text, nullptr, false);
  if (j.is_discarded() || !j.is_object() || !j.contains("nodes") || !j["nodes"].is_array() ||
      !j.contains("gaussians") || !j["gaussians"].is_number_unsigned()) {
    fail(source, "the index is not a hierarchy's JSON");
  }
  const nlohmann::json& nodes = j["nodes"];
  if (nodes.empty() || nodes.size() > kMostNodes) fail(source, std::to_string(nodes.size()) + " nodes");
  std::uint64_t leaves = 0;
  std::vector<std::int64_t> parent(nodes.size(), -1);  // a tree: every node but the root has one
  for (std::size_t i = 0; i < nodes.size(); ++i) {
    HierarchyNode n = parse_node(nodes[i], i, nodes.size(), file_bytes, index, source);
    const int expected = i == 0 ? 0 : parent[i] < 0 ? -1 : index.tree.nodes[static_cast<std::size_t>(parent[i])].level + 1;
    if (i > 0 && parent[i] < 0) fail(source, "node " + std::to_string(i) + " is no node's child");
    if (n.level != expected) fail(source, "node " + std::to_string(i) + ": level " + std::to_string(n.level) +
                                              ", its place in the tree says " + std::to_string(expected));
    for (const std::int32_t c : n.children) {
      if (c < 0) continue;
      if (parent[static_cast<std::size_t>(c)] >= 0) fail(source, "node " + std::to_string(c) + " has two parents");
      parent[static_cast<std::size_t>(c)] = static_cast<std::int64_t>(i);
    }
    if (n.leaf()) leaves += n.count;
    index.tree.nodes.push_back(n);
  }
  index.tree.model_gaussians = j["gaussians"].get<std::uint64_t>();
  if (leaves != index.tree.model_gaussians) {
    fail(source, "the leaves hold " + std::to_string(leaves) + " Gaussians, the index says " +
                     std::to_string(index.tree.model_gaussians));
  }
  return index;
}

Checkpoint read_hierarchy_page(std::string_view bytes, const HierarchyIndex& index, std::size_t node,
                               const std::filesystem::path& source) {
  if (node >= index.tree.nodes.size()) fail(source, "no node " + std::to_string(node));
  if (index.offset[node] + index.bytes[node] > bytes.size()) fail(source, "truncated before node " + std::to_string(node));
  const std::string where = source.string() + " (node " + std::to_string(node) + ")";
  Checkpoint page = decode_compact_checkpoint(bytes.substr(index.offset[node], index.bytes[node]), where);
  if (page.mixture.size() != index.tree.nodes[node].count) {
    fail(source, "node " + std::to_string(node) + " holds " + std::to_string(page.mixture.size()) +
                     " Gaussians, its index entry says " + std::to_string(index.tree.nodes[node].count));
  }
  return page;
}

Hierarchy load_hierarchy_file(const std::filesystem::path& path, const GaussianMixture* leaves) {
  const std::string bytes = io::read_file(path);
  const HierarchyIndex index = read_hierarchy_index(bytes, bytes.size(), path);
  Hierarchy h = index.tree;  // nodes only: their Gaussians follow, page by page
  // The leaves as load_hierarchy_model laid them out (leaf after leaf, in node order).
  const bool reuse = leaves != nullptr && leaves->size() == h.model_gaussians;
  std::size_t next_leaf = 0;
  for (std::size_t i = 0; i < h.nodes.size(); ++i) {
    h.nodes[i].first = h.gaussians.size();
    if (reuse && h.nodes[i].leaf()) {
      for (std::size_t k = 0; k < h.nodes[i].count; ++k) h.gaussians.push_back((*leaves)[next_leaf++]);
      continue;
    }
    const Checkpoint page = read_hierarchy_page(bytes, index, i, path);
    for (const GaussianParams& g : page.mixture) h.gaussians.push_back(g);
  }
  return h;
}

Hierarchy hierarchy_of(const std::filesystem::path& path, const Checkpoint& model, const HierarchyOptions& options) {
  char head[kHierarchyMagic.size()] = {};
  {
    std::ifstream in(path, std::ios::binary);
    in.read(head, sizeof head);
  }
  if (has_hierarchy_magic(std::string_view(head, sizeof head))) return load_hierarchy_file(path, &model.mixture);
  return build_hierarchy(model.mixture, options);
}

Checkpoint load_hierarchy_model(const std::filesystem::path& path) {
  const std::string bytes = io::read_file(path);
  const HierarchyIndex index = read_hierarchy_index(bytes, bytes.size(), path);
  Checkpoint model;
  model.mixture.reserve(index.tree.model_gaussians);
  for (std::size_t i = 0; i < index.tree.nodes.size(); ++i) {
    if (i != 0 && !index.tree.nodes[i].leaf()) continue;
    Checkpoint page = read_hierarchy_page(bytes, index, i, path);
    if (i == 0) model.meta = std::move(page.meta);
    if (!index.tree.nodes[i].leaf()) continue;
    for (const GaussianParams& g : page.mixture) model.mixture.push_back(g);
  }
  return model;
}

}  // namespace hisnegs::gmf
