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
  // kBuffers: topology and every leaf buffer's chunk sizes; kTopology: topology only
  // (point data and point index grids, whose leaves state their own sizes);
  // kHeader: metadata and transform only (a tree configuration this walk does not know).
  enum class Depth { kHeader, kTopology, kBuffers } depth = Depth::kHeader;
  std::int64_t leaves = 0;  // leaf nodes in the topology (0 below kTopology)
};

struct VdbFileCheck {
  std::uint32_t file_version = 0;
  std::vector<VdbGridCheck> grids;
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

// The grid the walk saw under `unique_name`, or nullptr.
const VdbGridCheck* find_grid(const VdbFileCheck& check, const std::string& unique_name);

// Whether OpenVDB may read the values of the grid named `unique_name`: the walk
// checked every leaf buffer of it (kBuffers), or of the grid it is an instance of.
// Anything else (point data, whose attribute arrays state their own sizes; tree
// configurations the walk does not know) is read as metadata and transform only.
bool values_checked(const VdbFileCheck& check, const std::string& unique_name);

}  // namespace hisnegs::io
