// SPDX-License-Identifier: Apache-2.0
// The hierarchy file (`.hgw`, docs/file-formats.md "Hierarchy file"): a small
// checksummed index of a gmf::Hierarchy's nodes (box, level, children, Gaussian
// count, detail, byte range) followed by one compact page (a whole `.hgs` file,
// quantized relative to the node's own Gaussians, checksummed) per node, so that a
// reader with HTTP range requests fetches the index, then the pages it draws.
// Every value read is bounded before it sizes anything.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>

#include "gmf/core/checkpoint.hpp"
#include "gmf/core/compact_checkpoint.hpp"
#include "gmf/core/hierarchy.hpp"

namespace hisnegs::gmf {

inline constexpr std::array<char, 8> kHierarchyMagic = {'\x89', 'H', 'G', 'W', '\r', '\n', '\x1a', '\n'};
inline constexpr std::uint32_t kHierarchyFormatVersion = 1;
// Bytes before the index: magic, version u32, flags u32, index size u64.
inline constexpr std::size_t kHierarchyHeadBytes = 24;

// The index: the nodes with their pages' byte ranges (absolute offsets).
struct HierarchyIndex {
  Hierarchy tree;                        // nodes only (tree.gaussians empty), model_gaussians set
  std::vector<std::uint64_t> offset;     // per node, its page's first byte
  std::vector<std::uint64_t> bytes;      // per node, its page's size
  std::uint64_t index_end = 0;           // the first byte after the index's CRC
};

// The file of `h` with the model's metadata `meta` (on the root's page; the other
// pages carry none) and `options` for every page, but for the position bits: each
// page takes as few as keep its centres' step at most a whole-model file's (the
// root cell over 2^position_bits), and at least 8.
[[nodiscard]] std::string encode_hierarchy_file(const Hierarchy& h, const CheckpointMeta& meta,
                                                const CompactOptions& options = {});
// Writes it atomically (temp file + rename); returns the file's size.
std::uint64_t save_hierarchy_file(const std::filesystem::path& path, const Hierarchy& h, const CheckpointMeta& meta,
                                  const CompactOptions& options = {});

// Whether `bytes` starts with kHierarchyMagic.
[[nodiscard]] bool has_hierarchy_magic(std::string_view bytes);
// The index of a file whose first bytes are `head` (the whole file, or at least
// kHierarchyHeadBytes + its index + 4) and whose size is `file_bytes`: magic,
// version, the index's size (at most 64 MiB and within the file), its CRC-32,
// then every node (a tree: children after their parent, in range, one parent each,
// levels one below it; counts at most 10^6;
// boxes finite; page ranges after the index and within the file; the leaves' counts
// adding up to the model's). Throws io::InputError "SOURCE: hierarchy: problem".
[[nodiscard]] HierarchyIndex read_hierarchy_index(std::string_view head, std::uint64_t file_bytes,
                                                  const std::filesystem::path& source);
// Node `node`'s Gaussians from the whole file `bytes` (its page decoded and checked:
// the count the index says).
[[nodiscard]] Checkpoint read_hierarchy_page(std::string_view bytes, const HierarchyIndex& index, std::size_t node,
                                             const std::filesystem::path& source);
// The whole hierarchy a file holds (Hierarchy::gaussians node after node, in the
// index's order), every page decoded and checked; but with `leaves`, the model
// load_hierarchy_model read from this file (leaf after leaf), the leaf pages are
// taken from it instead of being decoded a second time.
[[nodiscard]] Hierarchy load_hierarchy_file(const std::filesystem::path& path,
                                            const GaussianMixture* leaves = nullptr);
// The hierarchy of the checkpoint `model` loaded from `path`: the file's own for a
// `.hgw` (its leaves taken from `model`), else build_hierarchy of the model with
// `options`.
[[nodiscard]] Hierarchy hierarchy_of(const std::filesystem::path& path, const Checkpoint& model,
                                     const HierarchyOptions& options = {});
// The model a hierarchy file holds: its leaves' Gaussians, leaf after leaf, and the
// root page's metadata (load_checkpoint calls this for files with the magic).
[[nodiscard]] Checkpoint load_hierarchy_model(const std::filesystem::path& path);

}  // namespace hisnegs::gmf
