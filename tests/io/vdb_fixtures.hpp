// SPDX-License-Identifier: Apache-2.0
// .vdb files written by OpenVDB itself, for tests of io/vdb_validate. The grid
// templates live in vdb_fixtures.cpp (compiled unoptimized, beside the tests) so
// that the tests themselves need no OpenVDB header: one TU instantiating every
// grid type is the slowest compile in the project.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace hisnegs::testing {

// Whether OpenVDB knows metadata type `type` (the predicate validate_vdb_file takes).
bool vdb_metadata_registered(const std::string& type);

// The .vdb format version this OpenVDB writes.
std::uint32_t openvdb_file_version();

// The compressions OpenVDB offers: Blosc and zip with the active mask, the mask
// alone, none, Blosc alone.
std::vector<std::uint32_t> vdb_compressions();

// What write_every_kind_vdb wrote, in file order.
struct EveryKindFile {
  std::vector<std::string> names;  // float double vec3s int32 bool mask half instance
  std::int64_t float_leaves = 0;   // leaves of the "float" grid
};

// Grids of every value type and map hisnegs' walk knows (float with a uniform map,
// double with an affine map, vec3s with scale-translate, int32 with translation,
// bool, mask, half floats with a frustum, an instance of the float grid) and file
// metadata of four types, written with `compression`.
EveryKindFile write_every_kind_vdb(const std::filesystem::path& path, std::uint32_t compression);

// A points grid `name` of four points (NullCodec, Blosc); returns its leaf count.
std::int64_t write_points_vdb(const std::filesystem::path& path, const std::string& name = "points");

// A small float grid "volume" (a sphere of radius 6) with a string metadata
// "source" = "a.tif", through io::write_vdb_file.
void write_small_vdb(const std::filesystem::path& path);

}  // namespace hisnegs::testing
