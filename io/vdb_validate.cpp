// SPDX-License-Identifier: Apache-2.0
#include "io/vdb_validate.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <tuple>

#include "io/error.hpp"
#include "io/hash.hpp"

namespace hisnegs::io {
namespace {

// OpenVDB's file format numbers (openvdb/version.h, OPENVDB_FILE_VERSION_*).
constexpr std::uint32_t kMinVersion = 222;   // NODE_MASK_COMPRESSION: per-grid compression, node metadata
constexpr std::uint32_t kMaxVersion = 224;   // MULTIPASS_IO, written by OpenVDB 6 to 11
constexpr std::int64_t kMagic = 0x56444220;  // "VDB " little-endian
constexpr std::uint32_t kCompressZip = 0x1, kCompressActiveMask = 0x2, kCompressBlosc = 0x4;
constexpr int kMaxMapNesting = 4;                 // a frustum map holds a second map; nothing nests deeper
constexpr std::uint32_t kMultiPassVersion = 224;  // OPENVDB_FILE_VERSION_MULTIPASS_IO: point data grids
constexpr const char* kPointDataTree = "Tree_ptdataidx32_5_4_3";  // points::PointDataTree

// The 64-bit FNV-1a of bytes [from, to) of `in` (nullopt if they cannot be read).
std::optional<std::uint64_t> range_fnv1a64(std::istream& in, std::int64_t from, std::int64_t to) {
  in.clear();
  in.seekg(from);
  std::uint64_t h = fnv1a64(nullptr, 0);
  std::vector<char> buf(std::size_t{1} << 16);
  for (std::int64_t left = to - from; left > 0;) {
    const auto n = static_cast<std::streamsize>(std::min<std::int64_t>(left, static_cast<std::int64_t>(buf.size())));
    if (!in.read(buf.data(), n)) return std::nullopt;
    h = fnv1a64(buf.data(), static_cast<std::size_t>(n), h);
    left -= n;
  }
  return h;
}

// Sequential little-endian reads from the file with every length checked against
// what is left of it. Failures throw InputError "PATH: damaged .vdb: WHAT at byte N".
class Walker {
 public:
  explicit Walker(const std::filesystem::path& path) : path_(path), in_(path, std::ios::binary) {
    if (!in_) fail_input(path, "cannot open");
    std::error_code ec;
    size_ = static_cast<std::int64_t>(std::filesystem::file_size(path, ec));
    if (ec) fail_input(path, "cannot read its size: " + ec.message());
  }

  [[nodiscard]] std::int64_t pos() const { return pos_; }
  [[nodiscard]] std::int64_t size() const { return size_; }
  [[nodiscard]] std::int64_t left() const { return size_ - pos_; }
  [[nodiscard]] const std::filesystem::path& path() const { return path_; }

  [[noreturn]] void fail(const std::string& what) const {
    fail_input(path_, "damaged .vdb: " + what + " at byte " + std::to_string(pos_));
  }

  void need(std::int64_t bytes, const char* what) const {
    if (bytes < 0 || bytes > left())
      fail(std::string(what) + " needs " + std::to_string(bytes) + " bytes, the file has " +
           std::to_string(std::max<std::int64_t>(left(), 0)) + " left");
  }

  void read_bytes(void* out, std::int64_t bytes, const char* what) {
    need(bytes, what);
    if (!in_.read(static_cast<char*>(out), bytes)) fail(std::string("cannot read ") + what);
    pos_ += bytes;
  }

  template <class T>
  T read(const char* what) {
    T v{};
    read_bytes(&v, sizeof(T), what);
    return v;
  }

  void skip(std::int64_t bytes, const char* what) {
    need(bytes, what);
    pos_ += bytes;
    in_.seekg(pos_);
  }

  void seek(std::int64_t to, const char* what) {
    if (to < 0 || to > size_) fail(std::string(what) + " " + std::to_string(to) + " is outside the file");
    pos_ = to;
    in_.clear();
    in_.seekg(pos_);
  }

  // The 64-bit FNV-1a of bytes [from, to) of the file; leaves the position at `to`.
  std::uint64_t hash(std::int64_t from, std::int64_t to) {
    seek(from, "checksum start");
    need(to - from, "checksummed grid");
    const std::optional<std::uint64_t> h = range_fnv1a64(in_, from, to);
    if (!h) fail("cannot read the checksummed grid");
    seek(to, "checksum end");
    return *h;
  }

  // OpenVDB's readString: a uint32 length and that many bytes. `max_keep` bytes are
  // returned (names and type names are short); longer strings are skipped over.
  std::string read_string(const char* what, std::size_t max_keep = 256) {
    const auto n = read<std::uint32_t>(what);
    need(n, what);
    std::string s(std::min<std::size_t>(n, max_keep), '\0');
    read_bytes(s.data(), static_cast<std::int64_t>(s.size()), what);
    if (n > s.size()) skip(static_cast<std::int64_t>(n - s.size()), what);
    return s;
  }

 private:
  std::filesystem::path path_;
  std::ifstream in_;
  std::int64_t size_ = 0;
  std::int64_t pos_ = 0;
};

// The fixed sizes of the metadata types OpenVDB registers (openvdb.cc), whose
// readValue reads sizeof(T) whatever size the file states.
std::optional<std::int64_t> fixed_metadata_size(const std::string& type) {
  static const std::map<std::string, std::int64_t> sizes = {
      {"bool", 1},   {"int32", 4},  {"int64", 8},  {"float", 4},  {"double", 8}, {"vec2i", 8},
      {"vec2s", 8},  {"vec2d", 16}, {"vec3i", 12}, {"vec3s", 12}, {"vec3d", 24}, {"vec4i", 16},
      {"vec4s", 16}, {"vec4d", 32}, {"mat4s", 64}, {"mat4d", 128}};
  const auto it = sizes.find(type);
  return it == sizes.end() ? std::nullopt : std::optional<std::int64_t>(it->second);
}

// io::DelayedLoadMetadata::readValue: a per-leaf byte mask and optional int64
// compressed sizes, each stored raw or as one Blosc chunk whose header states its
// decompressed size. OpenVDB reserves and resizes to what the file states.
void check_blosc_header(Walker& w, std::int64_t chunk_bytes, std::int64_t min_bytes, std::int64_t max_bytes,
                        const char* what);

void walk_delayed_load(Walker& w, std::int64_t num_bytes) {
  if (num_bytes == 0) return;
  const std::int64_t end = w.pos() + num_bytes;
  const auto count = w.read<std::uint32_t>("delayed-load count");
  // One mask byte per leaf: a leaf's topology alone takes 64 bytes of this file.
  if (static_cast<std::int64_t>(count) > w.size() / 64 + 1)
    w.fail("delayed-load metadata claims " + std::to_string(count) + " leaves");
  auto table = [&](std::int64_t elem, bool optional, const char* what) {
    const auto bytes = w.read<std::uint32_t>(what);
    if (optional && bytes == 0xFFFFFFFFu) return;  // no compressed sizes stored
    if (bytes > 0) {
      // OpenVDB writes its padded tables: up to one padding block more than `count`.
      check_blosc_header(w, bytes, elem * count, elem * count + 4096, what);
    } else {
      w.skip(elem * count, what);
    }
  };
  table(1, false, "delayed-load mask");
  table(8, true, "delayed-load sizes");
  if (w.pos() > end) w.fail("delayed-load metadata is longer than its stated " + std::to_string(num_bytes) + " bytes");
  w.seek(end, "end of delayed-load metadata");
}

// TypedMetadata<T>::asBool (!math::isZero) of a fixed-size value's bytes: any
// element nonzero; floating-point elements compare as numbers (-0 is zero, NaN not).
bool fixed_value_as_bool(const std::string& type, const std::vector<std::uint8_t>& bytes) {
  const bool single = type == "float" || type == "vec2s" || type == "vec3s" || type == "vec4s" || type == "mat4s";
  const bool dbl = type == "double" || type == "vec2d" || type == "vec3d" || type == "vec4d" || type == "mat4d";
  const std::size_t elem = single ? 4 : dbl ? 8 : 1;
  for (std::size_t i = 0; i + elem <= bytes.size(); i += elem) {
    if (single) {
      float v = 0;
      std::memcpy(&v, bytes.data() + i, 4);
      if (v != 0.0f) return true;
    } else if (dbl) {
      double v = 0;
      std::memcpy(&v, bytes.data() + i, 8);
      if (v != 0.0) return true;
    } else if (bytes[i] != 0) {
      return true;
    }
  }
  return false;
}

// What walk_metadata saw of the entries it is asked about.
struct MetadataSeen {
  // What GridBase::saveFloatAsHalf answers after reading these entries: the asBool
  // of the last entry named "is_saved_as_half_float" that OpenVDB keeps (unregistered
  // "__" types are dropped), false if none. OpenVDB reads a grid's values as halves
  // by that entry alone.
  bool half_float = false;
  std::int64_t checksums_pos = -1;  // the kVdbChecksumKey string's value
  std::string checksums;
};

// MetaMap::readMeta.
MetadataSeen walk_metadata(Walker& w, const std::function<bool(const std::string&)>& is_registered, const char* where) {
  constexpr std::string_view kHalfKey = "is_saved_as_half_float";
  constexpr std::size_t kMaxChecksums = 16 * 4096;
  MetadataSeen seen;
  const auto count = w.read<std::uint32_t>(where);
  // Each entry takes at least its two string lengths and its size: 12 bytes.
  if (static_cast<std::int64_t>(count) * 12 > w.left())
    w.fail(std::string(where) + " claims " + std::to_string(count) + " entries");
  for (std::uint32_t i = 0; i < count; ++i) {
    const std::string name = w.read_string("metadata name");
    const std::string type = w.read_string("metadata type");
    const auto num_bytes = static_cast<std::int64_t>(w.read<std::uint32_t>("metadata size"));
    w.need(num_bytes, "metadata value");
    const bool half_key = name == kHalfKey;
    if (type == "__delayedload") {
      walk_delayed_load(w, num_bytes);
      if (half_key) seen.half_float = false;  // DelayedLoadMetadata::asBool
    } else if (const auto fixed = fixed_metadata_size(type)) {
      if (num_bytes != *fixed)
        w.fail("metadata '" + printable(name, 64) + "' of type " + type + " states " + std::to_string(num_bytes) +
               " bytes, not " + std::to_string(*fixed));
      if (half_key) {
        std::vector<std::uint8_t> value(static_cast<std::size_t>(num_bytes));
        w.read_bytes(value.data(), num_bytes, "metadata value");
        seen.half_float = fixed_value_as_bool(type, value);
      } else {
        w.skip(num_bytes, "metadata value");
      }
    } else if (type == "string" && name == kVdbChecksumKey && num_bytes <= std::int64_t{kMaxChecksums}) {
      seen.checksums_pos = w.pos();
      seen.checksums.resize(static_cast<std::size_t>(num_bytes));
      w.read_bytes(seen.checksums.data(), num_bytes, "metadata value");
    } else if (type == "string" || !is_registered || !is_registered(type)) {
      w.skip(num_bytes, "metadata value");  // read verbatim: a string, or an unknown type kept as bytes
      if (half_key && type.rfind("__", 0) != 0) seen.half_float = num_bytes > 0;  // !empty()
    } else {
      w.fail("metadata '" + printable(name, 64) + "' has type '" + printable(type, 64) +
             "', which this reader cannot check");
    }
  }
  return seen;
}

// Transform::read: the map's type name, then the map (math/Maps.h read()).
void walk_map(Walker& w, int depth) {
  const std::string type = w.read_string("transform type");
  static const std::map<std::string, std::int64_t> sizes = {{"AffineMap", 128},
                                                            {"UnitaryMap", 128},
                                                            {"ScaleMap", 120},
                                                            {"UniformScaleMap", 120},
                                                            {"TranslationMap", 24},
                                                            {"ScaleTranslateMap", 144},
                                                            {"UniformScaleTranslateMap", 144}};
  if (const auto it = sizes.find(type); it != sizes.end()) {
    w.skip(it->second, "transform");
  } else if (type == "NonlinearFrustumMap" && depth < kMaxMapNesting) {
    w.skip(48 + 8 + 8, "frustum map");  // bounding box, taper, depth
    walk_map(w, depth + 1);
  } else {
    w.fail("unknown transform type '" + printable(type, 64) + "'");
  }
}

// The value type and node sizes of a "Tree_<type>_<log2dim>_..._<leaf log2dim>" grid.
struct TreeLayout {
  std::int64_t value_bytes = 0;       // sizeof(ValueType)
  std::int64_t half_value_bytes = 0;  // its half-float size (real types), else value_bytes
  std::vector<int> log2dims;          // root's child first, leaf last
  bool standard_leaf = false;         // LeafNode<T>: buffers walked chunk by chunk
  int bit_leaf_masks = 0;             // LeafNode<bool> (2) / <ValueMask> (1): masks per leaf buffer
  bool point_data = false;            // PointDataLeafNode: its background must be 0
};

std::optional<TreeLayout> tree_layout(const std::string& grid_type) {
  // sizeof(ValueType), its half size, and whether its leaves use LeafNode<T>'s IO.
  static const std::map<std::string, std::tuple<int, int, bool>> types = {
      {"float", {4, 2, true}},        {"double", {8, 2, true}},       {"int32", {4, 4, true}},
      {"int64", {8, 8, true}},        {"vec3s", {12, 6, true}},       {"vec3d", {24, 6, true}},
      {"vec3i", {12, 12, true}},      {"bool", {1, 1, false}},        {"mask", {1, 1, false}},
      {"ptdataidx32", {4, 4, false}}, {"ptdataidx64", {8, 8, false}}, {"ptidx32", {4, 4, false}},
      {"ptidx64", {8, 8, false}}};
  if (grid_type.rfind("Tree_", 0) != 0) return std::nullopt;
  std::vector<std::string> parts;
  std::stringstream ss(grid_type.substr(5));
  for (std::string part; std::getline(ss, part, '_');) parts.push_back(part);
  if (parts.size() < 2) return std::nullopt;
  const auto it = types.find(parts.front());
  if (it == types.end()) return std::nullopt;
  TreeLayout t;
  std::tie(t.value_bytes, t.half_value_bytes, t.standard_leaf) = it->second;
  t.bit_leaf_masks = parts.front() == "bool" ? 2 : parts.front() == "mask" ? 1 : 0;
  t.point_data = parts.front().rfind("ptdataidx", 0) == 0;
  for (std::size_t i = 1; i < parts.size(); ++i) {
    if (parts[i].size() != 1 || parts[i][0] < '1' || parts[i][0] > '7') return std::nullopt;
    t.log2dims.push_back(parts[i][0] - '0');
  }
  return t;
}

// NodeMask<L>: 2^(3L) bits (NodeMask<1> is one byte, the others whole 64-bit words).
std::int64_t mask_bytes(int log2dim) { return (std::int64_t{1} << (3 * log2dim)) / 8; }

std::int64_t popcount_bytes(const std::vector<std::uint8_t>& bytes, std::int64_t bits) {
  std::int64_t n = 0;
  for (std::int64_t i = 0; i < bits / 8; ++i) n += std::popcount(bytes[static_cast<std::size_t>(i)]);
  return n;
}

// A Blosc chunk of `chunk_bytes` whose header must state that many compressed bytes
// and [min_bytes, max_bytes] decompressed ones.
void check_blosc_header(Walker& w, std::int64_t chunk_bytes, std::int64_t min_bytes, std::int64_t max_bytes,
                        const char* what) {
  w.need(chunk_bytes, what);
  if (chunk_bytes < 16) w.fail(std::string(what) + ": a Blosc chunk of " + std::to_string(chunk_bytes) + " bytes");
  std::array<std::uint8_t, 16> h{};
  const std::int64_t start = w.pos();
  w.read_bytes(h.data(), 16, what);
  std::uint32_t nbytes = 0, cbytes = 0;
  std::memcpy(&nbytes, h.data() + 4, 4);
  std::memcpy(&cbytes, h.data() + 12, 4);
  if (nbytes < min_bytes || nbytes > max_bytes)
    w.fail(std::string(what) + ": a Blosc chunk of " + std::to_string(nbytes) + " bytes where " +
           std::to_string(min_bytes) + (max_bytes > min_bytes ? " to " + std::to_string(max_bytes) : std::string()) +
           " are expected");
  if (cbytes != chunk_bytes)
    w.fail(std::string(what) + ": a Blosc chunk stating " + std::to_string(cbytes) + " compressed bytes in " +
           std::to_string(chunk_bytes));
  w.seek(start + chunk_bytes, what);
}

// io::readData<T>: `bytes` of values, stored raw or as one Blosc / zlib chunk.
void walk_data(Walker& w, std::uint32_t compression, std::int64_t bytes) {
  if (compression & (kCompressBlosc | kCompressZip)) {
    const auto n = w.read<std::int64_t>("chunk size");
    if (n <= 0) {
      if (-n != bytes)
        w.fail("an uncompressed chunk of " + std::to_string(-n) + " bytes where " + std::to_string(bytes) +
               " are expected");
      w.skip(bytes, "chunk");
    } else if (compression & kCompressBlosc) {
      check_blosc_header(w, n, bytes, bytes, "chunk");
    } else {
      w.skip(n, "zip chunk");  // zlib inflates into the caller's buffer of `bytes`
    }
  } else {
    w.skip(bytes, "values");
  }
}

// io::readCompressedValues for `count` values under a node value mask with `active`
// bits set.
void walk_compressed_values(Walker& w, const TreeLayout& t, bool half, std::uint32_t compression, std::int64_t count,
                            std::int64_t active, int log2dim) {
  const auto meta = w.read<std::int8_t>("node compression flag");
  if (meta < 0 || meta > 6) w.fail("node compression flag " + std::to_string(meta));
  if (meta == 2 || meta == 4 || meta == 5) w.skip(t.value_bytes * (meta == 5 ? 2 : 1), "inactive values");
  if (meta == 3 || meta == 4 || meta == 5) w.skip(mask_bytes(log2dim), "selection mask");
  const bool mask_compressed = (compression & kCompressActiveMask) != 0 && meta != 6;
  const std::int64_t n = mask_compressed ? active : count;
  if (half) {
    if (n < 1) return;  // HalfReader reads nothing for no values
    walk_data(w, compression, n * t.half_value_bytes);
  } else {
    walk_data(w, compression, n * t.value_bytes);
  }
}

struct GridWalk {
  const TreeLayout& tree;
  bool half;
  std::uint32_t compression;
  bool buffers;                           // walk leaf buffers too
  std::vector<std::int64_t> leaf_active;  // per leaf in file order, its active voxels
};

// InternalNode::readTopology / LeafNode::readTopology, depth-first.
void walk_node_topology(Walker& w, GridWalk& g, std::size_t level) {
  const int l = g.tree.log2dims[level];
  const std::int64_t bytes = mask_bytes(l);
  const std::int64_t bits = std::int64_t{1} << (3 * l);
  if (level + 1 == g.tree.log2dims.size()) {  // a leaf: its value mask
    std::vector<std::uint8_t> mask(static_cast<std::size_t>(bytes));
    w.read_bytes(mask.data(), bytes, "leaf value mask");
    g.leaf_active.push_back(popcount_bytes(mask, bits));
    return;
  }
  // Children take at least their own masks: bound the count before recursing.
  std::vector<std::uint8_t> child_mask(static_cast<std::size_t>(bytes)), value_mask(child_mask.size());
  w.read_bytes(child_mask.data(), bytes, "child mask");
  w.read_bytes(value_mask.data(), bytes, "value mask");
  walk_compressed_values(w, g.tree, g.half, g.compression, bits, popcount_bytes(value_mask, bits), l);
  const std::int64_t children = popcount_bytes(child_mask, bits);
  if (children * mask_bytes(g.tree.log2dims[level + 1]) > w.left())
    w.fail("a node claims " + std::to_string(children) + " children");
  for (std::int64_t i = 0; i < children; ++i) walk_node_topology(w, g, level + 1);
}

// RootNode::readTopology (current format) and Tree::readTopology's buffer count.
void walk_topology(Walker& w, GridWalk& g) {
  const auto buffer_count = w.read<std::int32_t>("buffer count");
  if (buffer_count != 1) w.fail("buffer count " + std::to_string(buffer_count) + " (must be 1)");
  if (g.tree.point_data) {
    // PointDataLeafNode asserts when made with a value other than zero, and
    // readTopology makes every leaf with the background.
    std::array<std::uint8_t, 8> background{};
    w.read_bytes(background.data(), g.tree.value_bytes, "background value");
    if (std::any_of(background.begin(), background.end(), [](std::uint8_t b) { return b != 0; }))
      w.fail("a point data tree's background is not 0");
  } else {
    w.skip(g.tree.value_bytes, "background value");
  }
  const auto tiles = static_cast<std::int64_t>(w.read<std::uint32_t>("root tile count"));
  const auto children = static_cast<std::int64_t>(w.read<std::uint32_t>("root child count"));
  const std::int64_t tile_bytes = 12 + g.tree.value_bytes + 1;
  const std::int64_t child_bytes = 12 + 2 * mask_bytes(g.tree.log2dims.front());
  if (tiles * tile_bytes + children * child_bytes > w.left())
    w.fail("the root claims " + std::to_string(tiles) + " tiles and " + std::to_string(children) + " children");
  // OpenVDB keys root entries by origin in a std::map and reads the children's
  // buffers in that map's order: origins must be distinct, and children must come
  // in increasing order for their buffers to follow the topology.
  int total_log2 = 0;
  for (int l : g.tree.log2dims) total_log2 += l;
  const std::int32_t align = static_cast<std::int32_t>((std::int64_t{1} << total_log2) - 1);
  std::vector<std::array<std::int32_t, 3>> origins;
  origins.reserve(static_cast<std::size_t>(tiles + children));
  auto read_origin = [&](const char* what) {
    std::array<std::int32_t, 3> o{};
    w.read_bytes(o.data(), 12, what);
    for (std::int32_t c : o)
      if (c & align) w.fail(std::string(what) + " " + std::to_string(c) + " is not on the root's grid");
    return o;
  };
  for (std::int64_t i = 0; i < tiles; ++i) {
    origins.push_back(read_origin("root tile origin"));
    w.skip(g.tree.value_bytes + 1, "root tile value");
  }
  std::optional<std::array<std::int32_t, 3>> previous;
  for (std::int64_t i = 0; i < children; ++i) {
    const auto o = read_origin("root child origin");
    if (previous && !(*previous < o)) w.fail("root children are not in increasing order");
    previous = o;
    origins.push_back(o);
    walk_node_topology(w, g, 0);
  }
  std::sort(origins.begin(), origins.end());
  if (std::adjacent_find(origins.begin(), origins.end()) != origins.end()) w.fail("two root entries share an origin");
}

// LeafNode::readBuffers for every leaf, in the topology's order.
void walk_buffers(Walker& w, const GridWalk& g) {
  const int l = g.tree.log2dims.back();
  if (g.tree.bit_leaf_masks > 0) {
    // LeafNode<bool>: value mask, origin, value bits; LeafNode<ValueMask>: value mask,
    // origin. Fixed sizes, whatever the compression flags.
    const std::int64_t record = mask_bytes(l) * g.tree.bit_leaf_masks + 12;
    w.skip(record * static_cast<std::int64_t>(g.leaf_active.size()), "bit leaf buffers");
    return;
  }
  for (const std::int64_t active : g.leaf_active) {
    w.skip(mask_bytes(l), "leaf value mask");
    walk_compressed_values(w, g.tree, g.half, g.compression, std::int64_t{1} << (3 * l), active, l);
  }
}

// ---- PointDataGrid buffers (OpenVDB 6-11, format 224: Grid::readBuffers with
// multi-pass IO over PointDataLeafNode<PointDataIndex32, 3>::readBuffers). Every
// count and size OpenVDB sizes an allocation, a loop or an assert by is bounded
// here by the bytes the file holds; a layout this walk does not know (codecs other
// than "null", group attributes) is left unread (false).

// AttributeArray flags and serialization flags (points/AttributeArray.h).
constexpr std::uint8_t kAttrConstantStride = 0x8, kAttrPartialRead = 0x20;
constexpr std::uint8_t kWriteStrided = 0x1, kWriteUniform = 0x2, kWritePaged = 0x8;
constexpr std::int64_t kPageSize = 1 << 20;  // compression::PageSize
// compression::bloscCompress pads inputs of 49..127 bytes with zeros to 128: such a
// chunk states 128 bytes, which bloscDecompress accepts for any expected size <= 128.
constexpr std::int64_t kBloscPadBytes = 128;
std::int64_t blosc_max_bytes(std::int64_t expected) { return std::max(expected, kBloscPadBytes); }

// sizeof(ValueType) of an attribute stored with the "null" codec.
std::optional<std::int64_t> attribute_value_bytes(const std::string& type, const std::string& codec) {
  static const std::map<std::string, std::int64_t> sizes = {
      {"bool", 1},   {"int8", 1},   {"int16", 2},  {"int32", 4},  {"int64", 8},  {"float", 4},
      {"double", 8}, {"vec3i", 12}, {"vec3s", 12}, {"vec3d", 24}, {"quats", 16}, {"quatd", 32},
      {"mat3s", 36}, {"mat3d", 72}, {"mat4s", 64}, {"mat4d", 128}};
  if (codec != "null") return std::nullopt;
  const auto it = sizes.find(type);
  return it == sizes.end() ? std::nullopt : std::optional<std::int64_t>(it->second);
}

// AttributeSet::Descriptor::validName.
bool valid_attribute_name(const std::string& name) {
  return !name.empty() && std::all_of(name.begin(), name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '|' || c == ':';
  });
}

// AttributeSet::Descriptor::read: the attributes' value sizes, or nullopt for a
// layout this walk does not know.
std::optional<std::vector<std::int64_t>> walk_descriptor(Walker& w,
                                                         const std::function<bool(const std::string&)>& is_registered) {
  const auto count = w.read<std::uint64_t>("attribute count");
  // OpenVDB makes a vector of `count` name pairs before reading them: each takes at
  // least three string lengths and a position (20 bytes); the pass count is 16-bit.
  if (count > static_cast<std::uint64_t>(w.left() / 20) || count > 32765)
    w.fail("the point descriptor claims " + std::to_string(count) + " attributes");
  std::vector<std::int64_t> value_bytes;
  bool known = true;
  for (std::uint64_t i = 0; i < count; ++i) {
    const std::string type = w.read_string("attribute type");
    const std::string codec = w.read_string("attribute codec");
    const std::optional<std::int64_t> bytes = attribute_value_bytes(type, codec);
    known = known && bytes.has_value();
    value_bytes.push_back(bytes.value_or(0));
  }
  std::vector<char> seen(count, 0);
  for (std::uint64_t i = 0; i < count; ++i) {
    const std::string name = w.read_string("attribute name");
    const auto pos = w.read<std::uint64_t>("attribute position");
    if (!valid_attribute_name(name)) w.fail("attribute name '" + printable(name, 64) + "'");
    // Positions index the attribute arrays: each of 0..count-1 once.
    if (pos >= count || seen[pos]) w.fail("attribute '" + name + "' at position " + std::to_string(pos));
    seen[pos] = 1;
  }
  const auto groups = w.read<std::uint64_t>("group count");
  if (groups > static_cast<std::uint64_t>(w.left() / 12))
    w.fail("the point descriptor claims " + std::to_string(groups) + " groups");
  for (std::uint64_t i = 0; i < groups; ++i) {
    (void)w.read_string("group name");
    w.skip(8, "group offset");
  }
  (void)walk_metadata(w, is_registered, "attribute metadata");
  if (!known || groups > 0) return std::nullopt;
  return value_bytes;
}

// One attribute array of one leaf, as AttributeArray::readMetadata states it.
struct PointArray {
  std::int64_t bytes = 0;  // mCompressedBytes: what its buffer pass reads
  std::int64_t data = 0;   // the bytes its values take once read
  bool uniform = false, paged = false;
};

// compression::PagedInputStream: the size pass reads a page header whenever the
// previous page is used up; handles must fill pages exactly, or OpenVDB asserts
// (or reads a page it never loaded).
struct PageStream {
  std::int64_t index = 0, size = 0;                          // mByteIndex, mUncompressedBytes
  std::vector<std::pair<std::int32_t, std::int64_t>> pages;  // (compressed bytes, uncompressed bytes)
};

// What a file of this size may plausibly make OpenVDB allocate for its point
// arrays and pages (each paged page twice when decompressing, each array once).
struct PointBudget {
  std::int64_t limit = 0, total = 0;
  void add(Walker& w, std::int64_t bytes, const char* what) {
    total += bytes;
    if (total > limit) w.fail(std::string("point ") + what + " claim more than " + std::to_string(limit) + " bytes");
  }
};

// AttributeArray::readMetadata of one array whose values take `value_bytes` each.
PointArray read_point_array(Walker& w, std::int64_t value_bytes, PointBudget& budget) {
  const auto bytes = w.read<std::uint64_t>("attribute bytes");
  const auto flags = w.read<std::uint8_t>("attribute flags");
  const auto serialization = w.read<std::uint8_t>("attribute serialization flags");
  const auto size = static_cast<std::int64_t>(w.read<std::uint32_t>("attribute size"));
  const std::int64_t stride =
      (serialization & kWriteStrided) ? static_cast<std::int64_t>(w.read<std::uint32_t>("attribute stride")) : 1;
  if ((flags & kAttrPartialRead) || serialization >= 0x10)
    w.fail("attribute flags " + std::to_string(flags) + "/" + std::to_string(serialization));
  PointArray a;
  a.uniform = serialization & kWriteUniform;
  a.paged = serialization & kWritePaged;
  // dataSize(), in 32 bits as OpenVDB computes it: no wrap-around allowed.
  const std::int64_t elements = (flags & kAttrConstantStride) ? size * stride : stride;
  if (elements <= 0 || elements > std::int64_t{0xFFFFFFFF})
    w.fail("an attribute of " + std::to_string(size) + " x " + std::to_string(stride) + " values");
  a.data = value_bytes * (a.uniform ? 1 : elements);
  if (bytes < 6 || bytes - 6 > std::uint64_t{0x7FFFFFFF}) w.fail("attribute bytes " + std::to_string(bytes));
  a.bytes = static_cast<std::int64_t>(bytes - 6);  // less the flags and size fields
  // Paged and uncompressed arrays hold exactly their values; a Blosc chunk is
  // checked against them where it is read.
  if ((a.paged || a.uniform) && a.bytes != a.data)
    w.fail("an attribute stating " + std::to_string(a.bytes) + " bytes for " + std::to_string(a.data));
  budget.add(w, a.data, "attributes");
  return a;
}

// Pass 1: the first leaf's descriptor, shared by the leaves after it when its
// header says so (OpenVDB's writer always does); then every leaf's array metadata.
// nullopt for a layout this walk does not know; `n` is set to the attribute count.
std::optional<std::vector<std::vector<PointArray>>> walk_point_metadata(
    Walker& w, std::int64_t leaves, const std::function<bool(const std::string&)>& is_registered, PointBudget& budget,
    std::size_t& n) {
  std::optional<std::vector<std::int64_t>> attrs;
  std::vector<std::vector<PointArray>> arrays;
  bool shared = false, known = true;
  for (std::int64_t leaf = 0; leaf < leaves; ++leaf) {
    if (!shared) {
      const auto header = w.read<std::uint8_t>("point leaf header");
      if (header > 3) w.fail("point leaf header " + std::to_string(header));
      const std::optional<std::vector<std::int64_t>> these = walk_descriptor(w, is_registered);
      if (header & 2)
        w.skip(static_cast<std::int64_t>(
                   std::min<std::uint64_t>(w.read<std::uint64_t>("point header skip"), std::uint64_t{1} << 62)),
               "point header skip");
      if (!these) known = false;
      if (attrs && these && *these != *attrs) w.fail("point leaves disagree on their attributes");
      if (!attrs) attrs = these.value_or(std::vector<std::int64_t>());
      shared = header & 1;
    }
    if (!known) return std::nullopt;
    std::vector<PointArray> per;
    for (const std::int64_t value_bytes : *attrs) per.push_back(read_point_array(w, value_bytes, budget));
    arrays.push_back(std::move(per));
  }
  n = attrs ? attrs->size() : 0;
  return arrays;
}

// Passes 2..n+1: each paged array takes a handle in its attribute's page stream.
std::vector<PageStream> walk_page_sizes(Walker& w, const std::vector<std::vector<PointArray>>& arrays, std::size_t n,
                                        PointBudget& budget) {
  std::vector<PageStream> streams(n);
  for (std::size_t i = 0; i < n; ++i) {
    PageStream& s = streams[i];
    for (const std::vector<PointArray>& per : arrays) {
      const PointArray& a = per[i];
      if (!a.paged) continue;
      if (s.index == s.size) {
        const auto compressed = w.read<std::int32_t>("page size");
        const std::int64_t uncompressed =
            compressed > 0 ? std::int64_t{w.read<std::int32_t>("page uncompressed size")} : -std::int64_t{compressed};
        if (compressed == 0 || compressed == INT32_MIN || uncompressed <= 0 ||
            uncompressed > std::max<std::int64_t>(kPageSize, a.bytes))
          w.fail("a page of " + std::to_string(compressed) + " / " + std::to_string(uncompressed) + " bytes");
        budget.add(w, 2 * blosc_max_bytes(uncompressed), "pages");  // Page::decompress holds twice the page
        s.pages.emplace_back(compressed, uncompressed);
        s.size = uncompressed;
        s.index = 0;
      }
      s.index += a.bytes;
      if (s.index > s.size) w.fail("an attribute crosses the end of its page");
    }
    if (s.index != s.size) w.fail("an attribute page is not used up");
  }
  return streams;
}

// Passes n+3..2n+2: the arrays' values, page by page.
void walk_point_values(Walker& w, const std::vector<std::vector<PointArray>>& arrays,
                       const std::vector<PageStream>& streams) {
  for (std::size_t i = 0; i < streams.size(); ++i) {
    std::size_t page = 0;
    std::int64_t index = 0, size = 0;
    for (const std::vector<PointArray>& per : arrays) {
      const PointArray& a = per[i];
      if (a.paged) {
        if (index == size) {
          const auto [compressed, uncompressed] = streams[i].pages.at(page++);
          if (compressed > 0)
            check_blosc_header(w, compressed, uncompressed, blosc_max_bytes(uncompressed), "attribute page");
          else
            w.skip(-std::int64_t{compressed}, "attribute page");
          index = 0;
          size = uncompressed;
        }
        index += a.bytes;
        continue;
      }
      // TypedAttributeArray::readBuffers: a Blosc flag unless uniform, then the bytes.
      const std::uint8_t blosc = a.uniform ? 0 : w.read<std::uint8_t>("attribute compression");
      if (blosc == 1)
        check_blosc_header(w, a.bytes, a.data, blosc_max_bytes(a.data), "attribute");
      else if (a.bytes != a.data)
        w.fail("an attribute of " + std::to_string(a.bytes) + " bytes for " + std::to_string(a.data));
      else
        w.skip(a.bytes, "attribute");
    }
  }
}

bool walk_point_buffers(Walker& w, GridWalk& g, const std::function<bool(const std::string&)>& is_registered) {
  const auto leaves = static_cast<std::int64_t>(g.leaf_active.size());
  const auto passes = w.read<std::uint16_t>("point pass count");
  w.skip(2 * leaves, "voxel buffer sizes");  // pass 0
  PointBudget budget{std::max<std::int64_t>(std::int64_t{64} << 20, 16 * w.size()), 0};
  std::size_t n = 0;
  const std::optional<std::vector<std::vector<PointArray>>> arrays =
      walk_point_metadata(w, leaves, is_registered, budget, n);
  if (!arrays) return false;
  // A tree without leaves reads nothing in any pass (OpenVDB writes 0 passes for it).
  if (leaves > 0 && passes != 4 + 2 * n)
    w.fail("point pass count " + std::to_string(passes) + " for " + std::to_string(n) + " attributes");
  const std::vector<PageStream> streams = walk_page_sizes(w, *arrays, n, budget);
  // Pass n+2: each leaf's voxel offsets (16-bit chunk sizes, 512 32-bit values).
  for (std::int64_t leaf = 0; leaf < leaves; ++leaf) {
    w.skip(64, "point leaf value mask");
    const auto bytes16 = w.read<std::uint16_t>("point offsets size");
    if (bytes16 == 0xFFFF)
      w.skip(512 * 4, "point offsets");
    else
      check_blosc_header(w, bytes16, 512 * 4, 512 * 4, "point offsets");
  }
  walk_point_values(w, *arrays, streams);
  return true;
}

void walk_grid(Walker& w, VdbGridCheck& grid, std::uint32_t version, std::int64_t grid_pos, std::int64_t block_pos,
               std::int64_t end_pos, const std::function<bool(const std::string&)>& is_registered) {
  w.seek(grid_pos, "grid position");
  const auto compression = w.read<std::uint32_t>("grid compression");
  if (compression & ~(kCompressZip | kCompressActiveMask | kCompressBlosc))
    w.fail("grid compression flags " + std::to_string(compression));
  // The descriptor's "_HalfFloat" suffix is not what OpenVDB reads the values by.
  grid.half_float = walk_metadata(w, is_registered, "grid metadata").half_float;
  walk_map(w, 0);
  if (grid.instance) {
    if (w.pos() > end_pos) w.fail("grid '" + printable(grid.name, 64) + "' runs past its stated end");
    return;
  }
  const std::optional<TreeLayout> tree = tree_layout(grid.grid_type);
  if (!tree) return;  // a tree configuration this walk does not know: header checks only
  GridWalk g{*tree, grid.half_float, compression, tree->standard_leaf || tree->bit_leaf_masks > 0, {}};
  walk_topology(w, g);
  grid.depth = VdbGridCheck::Depth::kTopology;
  grid.leaves = static_cast<std::int64_t>(g.leaf_active.size());
  if (w.pos() != block_pos)
    w.fail("grid '" + printable(grid.name, 64) + "' topology ends at byte " + std::to_string(w.pos()) +
           ", its descriptor says " + std::to_string(block_pos));
  if (grid.grid_type == kPointDataTree && version >= kMultiPassVersion) {  // (fromHalf does not apply to points)
    // PointDataGrid: every size its multi-pass buffers state, checked (or a layout
    // this walk does not know, left unread).
    if (!walk_point_buffers(w, g, is_registered)) return;
    grid.depth = VdbGridCheck::Depth::kBuffers;
    if (w.pos() != end_pos)
      w.fail("grid '" + printable(grid.name, 64) + "' point data ends at byte " + std::to_string(w.pos()) +
             ", its descriptor says " + std::to_string(end_pos));
    return;
  }
  if (!g.buffers) return;
  walk_buffers(w, g);
  grid.depth = VdbGridCheck::Depth::kBuffers;
  if (w.pos() != end_pos)
    w.fail("grid '" + printable(grid.name, 64) + "' data ends at byte " + std::to_string(w.pos()) +
           ", its descriptor says " + std::to_string(end_pos));
}

}  // namespace

VdbFileCheck validate_vdb_file(const std::filesystem::path& path,
                               const std::function<bool(const std::string&)>& is_registered_metadata) {
  Walker w(path);
  VdbFileCheck out;
  if (w.size() < 8 || w.read<std::int64_t>("magic number") != kMagic)
    fail_input(path, "not a .vdb file (no VDB magic number)");
  out.file_version = w.read<std::uint32_t>("file version");
  if (out.file_version < kMinVersion || out.file_version > kMaxVersion)
    fail_input(path, "unsupported .vdb file format version " + std::to_string(out.file_version) +
                         " (this reader takes " + std::to_string(kMinVersion) + " to " + std::to_string(kMaxVersion) +
                         ")");
  w.skip(8, "library version");
  if (w.read<std::uint8_t>("grid offsets flag") == 0)
    fail_input(path, "unsupported .vdb: written as a stream without grid offsets");
  std::array<char, 36> uuid{};
  w.read_bytes(uuid.data(), 36, "uuid");
  for (std::size_t i = 0; i < uuid.size(); ++i) {
    const bool dash = i == 8 || i == 13 || i == 18 || i == 23;
    const char c = uuid[i];
    if (dash ? c != '-' : !std::isxdigit(static_cast<unsigned char>(c))) w.fail("the uuid is not 36 characters of hex");
  }
  const MetadataSeen file_meta = walk_metadata(w, is_registered_metadata, "file metadata");
  out.checksums_pos = file_meta.checksums_pos;
  out.checksums = file_meta.checksums;
  const auto grids = w.read<std::int32_t>("grid count");
  // A descriptor takes at least three string lengths and three offsets.
  if (grids < 0 || std::int64_t{grids} * 36 > w.left()) w.fail("grid count " + std::to_string(grids));
  for (std::int32_t i = 0; i < grids; ++i) {
    VdbGridCheck grid;
    grid.name = w.read_string("grid name");
    grid.grid_type = w.read_string("grid type");
    constexpr std::string_view kHalf = "_HalfFloat";
    if (grid.grid_type.size() > kHalf.size() && grid.grid_type.ends_with(kHalf))
      grid.grid_type.resize(grid.grid_type.size() - kHalf.size());
    grid.instance_parent = w.read_string("instance parent name");
    grid.instance = !grid.instance_parent.empty();
    const auto grid_pos = w.read<std::int64_t>("grid position");
    const auto block_pos = w.read<std::int64_t>("block position");
    const auto end_pos = w.read<std::int64_t>("end position");
    // An instance has no tree of its own and no block position (0).
    const bool blocks_ok = grid.instance ? block_pos == 0 : grid_pos <= block_pos && block_pos <= end_pos;
    if (!(w.pos() <= grid_pos && grid_pos <= end_pos && blocks_ok && end_pos <= w.size()))
      w.fail("grid '" + printable(grid.name, 64) + "' has positions " + std::to_string(grid_pos) + ", " +
             std::to_string(block_pos) + ", " + std::to_string(end_pos) + " outside its place in the file");
    grid.grid_pos = grid_pos;
    grid.end_pos = end_pos;
    walk_grid(w, grid, out.file_version, grid_pos, block_pos, end_pos, is_registered_metadata);
    w.seek(end_pos, "end position");  // the next descriptor follows this grid
    out.grids.push_back(std::move(grid));
  }
  const bool have_checksums = out.checksums.size() == 16 * out.grids.size();
  for (std::size_t i = 0; i < out.grids.size(); ++i) {
    VdbGridCheck& g = out.grids[i];
    // Grids whose every value the walk checked need no checksum, except point data,
    // whose attribute values (not sizes) only the checksum covers.
    if (!have_checksums || g.instance || (g.depth == VdbGridCheck::Depth::kBuffers && g.grid_type != kPointDataTree))
      continue;
    g.checksum_match = out.checksums.compare(16 * i, 16, vdb_checksum_hex(w.hash(g.grid_pos, g.end_pos))) == 0;
  }
  return out;
}

std::string vdb_checksum_hex(std::uint64_t hash) {
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(hash));
  return hex;
}

std::optional<std::string> vdb_grid_checksums(const std::filesystem::path& path, const VdbFileCheck& check) {
  std::ifstream in(path, std::ios::binary);
  std::string out;
  for (const VdbGridCheck& g : check.grids) {
    const std::optional<std::uint64_t> h = range_fnv1a64(in, g.grid_pos, g.end_pos);
    if (!h) return std::nullopt;
    out += vdb_checksum_hex(*h);
  }
  return out;
}

const VdbGridCheck* find_grid(const VdbFileCheck& check, const std::string& unique_name) {
  const auto it = std::find_if(check.grids.begin(), check.grids.end(),
                               [&](const VdbGridCheck& g) { return g.name == unique_name; });
  return it == check.grids.end() ? nullptr : &*it;
}

bool values_checked(const VdbFileCheck& check, const std::string& unique_name) {
  const VdbGridCheck* g = find_grid(check, unique_name);
  if (g && g->instance) g = g->instance_parent == unique_name ? nullptr : find_grid(check, g->instance_parent);
  // Only the walk decides: a checksum anyone can recompute proves no size bounded.
  return g && !g->instance && g->depth == VdbGridCheck::Depth::kBuffers;
}

}  // namespace hisnegs::io
