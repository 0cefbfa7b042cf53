// SPDX-License-Identifier: Apache-2.0
// Structural check of a .vdb file before OpenVDB reads it. OpenVDB trusts every
// length and count in a file: a string length, a metadata size, a node count or a
// compressed-chunk size is allocated (or read into a fixed buffer) as found. This
// walks the file as OpenVDB's io::File would read it (header, file metadata, grid
// descriptors, each grid's metadata, transform, tree topology and leaf buffers) and
// checks every such number against the bytes the file really holds, reading only
// small fields and allocating nothing in proportion to what the file claims.
// No OpenVDB include: the layout is OpenVDB's documented file format 222-224.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

namespace hisnegs::io {

// What the walk could check of one grid.
struct VdbGridCheck {
  std::string name;             // the descriptor's unique name
  std::string grid_type;        // "Tree_float_5_4_3" (without a "_HalfFloat" suffix)
  bool half_float = false;      // values stored as halves: its "is_saved_as_half_float" metadata
  bool instance = false;        // shares another grid's tree (no topology of its own)
  std::string instance_parent;  // that grid's unique name (empty unless `instance`)
  // kBuffers: topology and every leaf buffer's chunk sizes (for a point data grid of
  // format 224, every count and size of its multi-pass buffers: descriptor, array
  // metadata, pages, voxel offsets); kTopology: topology only (point index grids,
  // point data with codecs or groups this walk does not know); kHeader: metadata and
  // transform only (a tree configuration this walk does not know).
  enum class Depth { kHeader, kTopology, kBuffers } depth = Depth::kHeader;
  std::int64_t leaves = 0;                 // leaf nodes in the topology (0 below kTopology)
  std::int64_t grid_pos = 0, end_pos = 0;  // its bytes: [grid_pos, end_pos)
  // Below kBuffers, or point data (and not an instance): whether its bytes match the
  // checksum hisnegs wrote for it (kVdbChecksumKey); nullopt when the file carries
  // none or the grid needs none. Integrity only: anyone can recompute it.
  std::optional<bool> checksum_match;
};

// File metadata hisnegs' .vdb writer adds: a string of 16 lowercase hex digits per
// grid, in file order, the 64-bit FNV-1a of that grid's bytes [grid_pos, end_pos).
// An unkeyed hash: it tells a file damaged or edited after export (point attribute
// values the walk cannot judge), never that its sizes are safe to read: an edited
// file can carry a recomputed checksum. Only the walk decides what OpenVDB reads.
inline constexpr const char* kVdbChecksumKey = "hisnegs_grid_fnv1a64";

struct VdbFileCheck {
  std::uint32_t file_version = 0;
  std::vector<VdbGridCheck> grids;
  std::int64_t checksums_pos = -1;  // byte offset of the kVdbChecksumKey string's value, if any
  std::string checksums;            // that value (empty if absent)
};

// Throws io::InputError "PATH: damaged .vdb: WHAT at byte N" (one line) for anything
// OpenVDB would read past the end of the file, allocate beyond it, or read out of
// step with how it was written; "PATH: not a .vdb file" for a wrong magic number and
// "PATH: unsupported .vdb ..." for format versions outside 222..224 and streams
// written without grid offsets. `is_registered_metadata(type)` is asked about a
// metadata type this walk does not know: if OpenVDB would parse it (rather than
// keep its bytes verbatim), the file is refused, since its size cannot be checked.
VdbFileCheck validate_vdb_file(const std::filesystem::path& path,
                               const std::function<bool(const std::string&)>& is_registered_metadata);

// 16 lowercase hex digits: one grid's entry in the kVdbChecksumKey string.
std::string vdb_checksum_hex(std::uint64_t hash);

// kVdbChecksumKey's value for the file at `path` that `check` describes: every
// grid's checksum, in file order (nullopt if the file cannot be read).
std::optional<std::string> vdb_grid_checksums(const std::filesystem::path& path, const VdbFileCheck& check);

// The grid the walk saw under `unique_name`, or nullptr.
const VdbGridCheck* find_grid(const VdbFileCheck& check, const std::string& unique_name);

// Whether OpenVDB may read the values of the grid named `unique_name`: the walk
// checked every size in its buffers (kBuffers), or in those of the grid it is an
// instance of. Anything else (tree configurations or point layouts the walk does not
// know) is read as metadata and transform only, whatever checksum the file carries.
bool values_checked(const VdbFileCheck& check, const std::string& unique_name);

}  // namespace hisnegs::io
