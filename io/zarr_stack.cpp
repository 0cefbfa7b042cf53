// SPDX-License-Identifier: Apache-2.0
// OME-Zarr metadata (Zarr v2/v3 arrays, OME-NGFF multiscales), region reads by
// chunk and shard, and the v0.4 pyramid writer. JSON through nlohmann-json, byte
// codecs through zarr_codecs (libblosc, zlib, libzstd).
#include "io/zarr_stack.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <tuple>
#include <limits>
#include <nlohmann/json.hpp>
#include <numeric>
#include <random>
#include <sstream>

#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/json_depth.hpp"
#include "io/zarr_codecs.hpp"

namespace hisnegs::io {
namespace fs = std::filesystem;
using nlohmann::json;

namespace zarr {

// The codecs between a chunk's values and its bytes, in encoding order.
struct Chain {
  std::vector<std::vector<int>> transposes;  // array -> array: encoded dim k is decoded dim order[k]
  bool big_endian = false;                   // array -> bytes
  std::shared_ptr<const struct Sharding> sharding;  // array -> bytes instead of plain bytes
  std::vector<ByteCodec> bytes;              // bytes -> bytes
  [[nodiscard]] std::string describe() const;
};

struct Sharding {
  std::vector<long long> inner;  // the inner chunk's shape
  Chain chain;                   // of each inner chunk
  Chain index;                   // of the index (bytes, crc32c)
  bool index_at_end = true;
};

struct Array {
  fs::path folder;
  int format = 2;
  std::vector<long long> shape, chunk;  // chunk: v3 sharded, the shard
  char kind = 'u';                      // u, i, f
  int size = 2;                         // bytes per value
  float fill = 0.0f;
  Chain chain;
  std::string key_prefix;  // "c" (v3 default keys) or ""
  char separator = '.';
  [[nodiscard]] fs::path chunk_path(const std::vector<long long>& index) const {
    std::string key = key_prefix;
    for (const long long i : index) {
      if (!key.empty()) key += separator;
      key += std::to_string(i);
    }
    return folder / key;
  }
};

std::string Chain::describe() const {
  std::string text;
  if (sharding) {
    std::string inner;
    for (const long long e : sharding->inner) inner += (inner.empty() ? "" : "x") + std::to_string(e);
    text = "sharding(inner " + inner + "; " + sharding->chain.describe() + ")";
  }
  for (const ByteCodec& c : bytes) {
    if (!text.empty()) text += "+";
    text += c.name() + (c.kind == ByteCodec::Kind::kBlosc ? "(" + c.blosc_cname + ")" : "");
  }
  return text.empty() ? "none" : text;
}

}  // namespace zarr

namespace {

using zarr::Array;
using zarr::ByteCodec;
using zarr::Chain;

constexpr long long kMaxChunkValues = 1LL << 28;   // a decoded chunk: at most 1 GiB of float32
constexpr long long kMaxInnerChunks = 1LL << 22;   // per shard
constexpr long long kMaxExtent = std::numeric_limits<int>::max();

std::string joined_extents(const std::vector<long long>& v) {
  std::string s;
  for (const long long e : v) s += (s.empty() ? "" : "x") + std::to_string(e);
  return s;
}

constexpr std::size_t kMaxMetadataBytes = std::size_t{16} << 20;
constexpr int kMaxJsonDepth = 64;

// Metadata as JSON: at most 16 MiB, nested at most 64 deep (copies and dump() of
// nlohmann's values recurse: a file of a million '[' would overflow the stack).
json read_json(const fs::path& file) {
  std::error_code ec;
  const auto bytes = fs::file_size(file, ec);
  if (!ec && bytes > kMaxMetadataBytes) fail_input(file, "is over 16 MiB; not Zarr metadata");
  const std::string text = read_file(file);
  if (!json_nests_within(text, kMaxJsonDepth)) fail_input(file, "nests JSON deeper than 64 levels; not Zarr metadata");
  try {
    return json::parse(text);
  } catch (const json::exception& e) {
    fail_input(file, std::string("is not valid JSON: ") + e.what());
  }
}

bool exists_entry(const fs::path& p) {
  std::error_code ec;
  return fs::exists(fs::symlink_status(p, ec));
}

// `j[key]` as T, or a one-line error naming the file and field.
template <class T>
T field(const json& j, const char* key, const fs::path& file) {
  if (!j.is_object() || !j.contains(key)) fail_input(file, std::string("has no field \"") + key + "\"");
  try {
    return j.at(key).get<T>();
  } catch (const json::exception&) {
    fail_input(file, std::string("field \"") + key + "\" = " + j.at(key).dump() + " has the wrong type");
  }
}

std::vector<long long> extents(const json& j, const char* key, const fs::path& file, long long max) {
  const json list = field<json>(j, key, file);
  const auto bad = [&](const std::string& why) { fail_input(file, std::string(key) + " = " + list.dump() + ": " + why); };
  if (!list.is_array() || list.empty() || list.size() > 5) bad("expected a list of 1 to 5 extents");
  std::vector<long long> v;
  for (const json& e : list) {
    if (!e.is_number_integer() || e.get<long long>() < 1 || e.get<long long>() > max) {
      bad("each must be an integer in [1, " + std::to_string(max) + "]");
    }
    v.push_back(e.get<long long>());
  }
  return v;
}

// The whole array's count of values must be one hisnegs can index (shape's product).
void check_values(const Array& a, const fs::path& file) {
  double n = 1;
  for (const long long e : a.shape) n *= static_cast<double>(e);
  if (n > 0x1p62) fail_input(file, "shape " + joined_extents(a.shape) + " holds more than 2^62 values");
}

void set_type(Array& a, const std::string& name, const fs::path& file) {
  static const std::pair<const char*, std::pair<char, int>> kTypes[] = {
      {"uint8", {'u', 1}}, {"uint16", {'u', 2}}, {"int16", {'i', 2}}, {"float32", {'f', 4}}};
  for (const auto& [n, t] : kTypes) {
    if (name == n) {
      a.kind = t.first;
      a.size = t.second;
      return;
    }
  }
  fail_input(file, "data type " + name + " is not read (uint8, uint16, int16, float32)");
}

std::string type_name(const Array& a) {
  if (a.kind == 'f') return "float32";
  if (a.kind == 'i') return "int16";
  return a.size == 1 ? "uint8" : "uint16";
}

float fill_of(const json& v, const fs::path& file) {
  if (v.is_null()) return 0.0f;
  if (v.is_number()) return v.get<float>();
  if (v.is_string()) {
    const auto s = v.get<std::string>();
    if (s == "NaN") return std::numeric_limits<float>::quiet_NaN();
    if (s == "Infinity") return std::numeric_limits<float>::infinity();
    if (s == "-Infinity") return -std::numeric_limits<float>::infinity();
    if (s.size() == 10 && s.rfind("0x", 0) == 0 && s.find_first_not_of("0123456789abcdefABCDEF", 2) == std::string::npos) {
      const auto bits = static_cast<std::uint32_t>(std::stoul(s.substr(2), nullptr, 16));  // v3: a float's bits
      float f = 0;
      std::memcpy(&f, &bits, 4);
      return f;
    }
  }
  fail_input(file, "fill_value = " + v.dump() + " is not read");
}

ByteCodec blosc_codec(const json& c, const fs::path& file, int size) {
  ByteCodec b;
  b.kind = ByteCodec::Kind::kBlosc;
  b.blosc_cname = c.value("cname", std::string("lz4"));
  b.typesize = static_cast<std::size_t>(size);
  if (b.blosc_cname.empty()) fail_input(file, "blosc has an empty cname");
  return b;
}

// A v2 `compressor` (null or an object with an id).
void v2_compressor(const json& c, Chain& chain, const fs::path& file, int size) {
  if (c.is_null()) return;
  const auto id = field<std::string>(c, "id", file);
  if (id == "blosc") {
    chain.bytes.push_back(blosc_codec(c, file, size));
  } else if (id == "zlib" || id == "gzip" || id == "zstd") {
    ByteCodec b;
    b.kind = id == "zlib" ? ByteCodec::Kind::kZlib : id == "gzip" ? ByteCodec::Kind::kGzip : ByteCodec::Kind::kZstd;
    chain.bytes.push_back(b);
  } else {
    fail_input(file, "compressor \"" + id + "\" is not read (blosc, zlib, gzip, zstd, none)");
  }
}

Array v2_array(const fs::path& folder) {
  const fs::path file = folder / ".zarray";
  const json j = read_json(file);
  Array a;
  a.folder = folder;
  a.format = 2;
  if (field<int>(j, "zarr_format", file) != 2) fail_input(file, "zarr_format is not 2");
  a.shape = extents(j, "shape", file, kMaxExtent);
  a.chunk = extents(j, "chunks", file, kMaxExtent);
  if (a.chunk.size() != a.shape.size()) fail_input(file, "chunks and shape have different numbers of axes");
  check_values(a, file);
  const auto dtype = field<std::string>(j, "dtype", file);
  static const std::pair<const char*, const char*> kDtypes[] = {
      {"u1", "uint8"}, {"u2", "uint16"}, {"i2", "int16"}, {"f4", "float32"}};
  const std::string body = dtype.size() == 3 ? dtype.substr(1) : dtype;
  const auto* t = std::find_if(std::begin(kDtypes), std::end(kDtypes), [&](const auto& p) { return body == p.first; });
  if (dtype.size() != 3 || std::string("<>|").find(dtype[0]) == std::string::npos || t == std::end(kDtypes)) {
    fail_input(file, "dtype \"" + dtype + "\" is not read (|u1, <u2, >u2, <i2, >i2, <f4, >f4)");
  }
  set_type(a, t->second, file);
  a.chain.big_endian = dtype[0] == '>';
  if (j.value("order", std::string("C")) != "C") fail_input(file, "order \"F\" is not read (write the array in C order)");
  if (j.contains("filters") && !j["filters"].is_null() && !j["filters"].empty()) {
    fail_input(file, "filters " + j["filters"].dump() + " are not read");
  }
  v2_compressor(j.contains("compressor") ? j["compressor"] : json(), a.chain, file, a.size);
  a.fill = fill_of(j.contains("fill_value") ? j["fill_value"] : json(), file);
  const std::string sep = j.value("dimension_separator", std::string("."));
  if (sep != "." && sep != "/") fail_input(file, "dimension_separator \"" + sep + "\" is not . or /");
  a.separator = sep[0];
  return a;
}

Chain v3_chain(const json& codecs, const fs::path& file, std::size_t ndim, int size);

// One v3 codec object into `chain` (which it may only extend in encoding order).
void v3_codec(const json& c, Chain& chain, bool& have_bytes, const fs::path& file, std::size_t ndim, int size) {
  const auto name = field<std::string>(c, "name", file);
  const json conf = c.contains("configuration") ? c["configuration"] : json::object();
  if (name == "transpose") {
    if (have_bytes) fail_input(file, "codec transpose after the bytes codec");
    std::vector<int> order;
    if (conf.contains("order") && conf["order"].is_string()) {  // the early spec's "C" / "F"
      order.resize(ndim);
      std::iota(order.begin(), order.end(), 0);
      if (conf["order"] == "F") std::reverse(order.begin(), order.end());
    } else {
      order = field<std::vector<int>>(conf, "order", file);
    }
    std::vector<int> sorted = order;
    std::sort(sorted.begin(), sorted.end());
    bool permutation = sorted.size() == ndim;
    for (std::size_t k = 0; permutation && k < sorted.size(); ++k) permutation = sorted[k] == static_cast<int>(k);
    if (!permutation) fail_input(file, "transpose order " + conf.dump() + " is not a permutation of the axes");
    chain.transposes.push_back(order);
  } else if (name == "bytes" || name == "endian") {
    if (have_bytes) fail_input(file, "two array-to-bytes codecs");
    have_bytes = true;
    chain.big_endian = conf.value("endian", std::string("little")) == "big";
  } else if (name == "sharding_indexed") {
    if (have_bytes) fail_input(file, "two array-to-bytes codecs");
    have_bytes = true;
    auto s = std::make_shared<zarr::Sharding>();
    s->inner = extents(conf, "chunk_shape", file, kMaxExtent);
    if (s->inner.size() != ndim) fail_input(file, "sharding chunk_shape has the wrong number of axes");
    s->chain = v3_chain(field<json>(conf, "codecs", file), file, ndim, size);
    s->index = v3_chain(conf.contains("index_codecs") ? conf["index_codecs"] : json::array({json{{"name", "bytes"}}}),
                        file, 1, 8);
    const json location = conf.contains("index_location") ? conf["index_location"] : json("end");
    if (location != "end" && location != "start") fail_input(file, "index_location " + location.dump() + " is not end or start");
    s->index_at_end = location == "end";
    if (s->chain.sharding) fail_input(file, "sharding_indexed inside sharding_indexed is not read");
    chain.sharding = s;
  } else if (name == "blosc" || name == "gzip" || name == "zstd" || name == "crc32c") {
    if (!have_bytes) fail_input(file, "codec " + name + " before the bytes codec");
    if (name == "blosc") {
      chain.bytes.push_back(blosc_codec(conf, file, size));
    } else {
      ByteCodec b;
      b.kind = name == "gzip" ? ByteCodec::Kind::kGzip : name == "zstd" ? ByteCodec::Kind::kZstd : ByteCodec::Kind::kCrc32c;
      chain.bytes.push_back(b);
    }
  } else {
    fail_input(file, "codec \"" + name + "\" is not read (bytes, transpose, blosc, gzip, zstd, crc32c, sharding_indexed)");
  }
}

Chain v3_chain(const json& codecs, const fs::path& file, std::size_t ndim, int size) {
  if (!codecs.is_array()) fail_input(file, "codecs is not a list");
  Chain chain;
  bool have_bytes = false;
  for (const json& c : codecs) v3_codec(c, chain, have_bytes, file, ndim, size);
  if (!have_bytes && size > 1) fail_input(file, "codecs name no bytes codec");
  if (chain.sharding && (!chain.transposes.empty() || !chain.bytes.empty())) {
    fail_input(file, "codecs around sharding_indexed (a transpose before it, a byte codec after it) are not read");
  }
  int compressors = 0;
  for (const ByteCodec& b : chain.bytes) compressors += b.kind != ByteCodec::Kind::kCrc32c ? 1 : 0;
  if (compressors > 1) fail_input(file, "codecs hold two compressors in a row; one is read");
  return chain;
}

Array v3_array(const fs::path& folder, const json& j) {
  const fs::path file = folder / "zarr.json";
  Array a;
  a.folder = folder;
  a.format = 3;
  a.shape = extents(j, "shape", file, kMaxExtent);
  set_type(a, field<std::string>(j, "data_type", file), file);
  const json grid = field<json>(j, "chunk_grid", file);
  if (grid.value("name", std::string()) != "regular") fail_input(file, "chunk_grid " + grid.dump() + " is not regular");
  a.chunk = extents(field<json>(grid, "configuration", file), "chunk_shape", file, kMaxExtent);
  if (a.chunk.size() != a.shape.size()) fail_input(file, "chunk_shape and shape have different numbers of axes");
  check_values(a, file);
  if (j.contains("storage_transformers") && !j["storage_transformers"].empty()) {
    fail_input(file, "storage_transformers " + j["storage_transformers"].dump() + " are not read");
  }
  a.chain = v3_chain(field<json>(j, "codecs", file), file, a.shape.size(), a.size);
  a.fill = fill_of(j.contains("fill_value") ? j["fill_value"] : json(), file);
  const json keys = j.contains("chunk_key_encoding") ? j["chunk_key_encoding"] : json{{"name", "default"}};
  const std::string encoding = keys.value("name", std::string("default"));
  const json kconf = keys.contains("configuration") ? keys["configuration"] : json::object();
  if (encoding == "default") {
    a.key_prefix = "c";
    a.separator = kconf.value("separator", std::string("/"))[0];
  } else if (encoding == "v2") {
    a.separator = kconf.value("separator", std::string("."))[0];
  } else {
    fail_input(file, "chunk_key_encoding \"" + encoding + "\" is not read");
  }
  if (a.separator != '.' && a.separator != '/') fail_input(file, "chunk key separator is not . or /");
  if (const auto& s = a.chain.sharding) {
    double inner = 1;
    for (std::size_t d = 0; d < a.chunk.size(); ++d) {
      if (a.chunk[d] % s->inner[d] != 0) fail_input(file, "the shard's chunk_shape is not a multiple of the inner chunk's");
      inner *= static_cast<double>(a.chunk[d]) / static_cast<double>(s->inner[d]);
    }
    if (inner > static_cast<double>(kMaxInnerChunks)) fail_input(file, "a shard holds " + number_text(inner) + " chunks; at most 2^22 are read");
  }
  return a;
}

// Whether `folder` holds an array's metadata (without reading it).
bool is_v3_array(const json& j) { return j.value("node_type", std::string()) == "array"; }

bool array_in_folder(const fs::path& folder) {
  return exists_entry(folder / ".zarray") ||
         (exists_entry(folder / "zarr.json") && is_v3_array(read_json(folder / "zarr.json")));
}

// The array in `folder` (v2 .zarray or v3 zarr.json), or nullopt when it is a group.
std::optional<Array> array_in(const fs::path& folder) {
  if (exists_entry(folder / ".zarray")) return v2_array(folder);
  if (exists_entry(folder / "zarr.json")) {
    const json j = read_json(folder / "zarr.json");
    if (is_v3_array(j)) return v3_array(folder, j);
  }
  return std::nullopt;
}

// The OME multiscales list of the group in `folder` (v0.4 .zattrs, v0.5 zarr.json
// attributes.ome), with the version; null when there is none.
std::pair<json, std::string> multiscales_of(const fs::path& folder) {
  json attrs;
  std::string version;
  if (exists_entry(folder / ".zattrs")) {
    attrs = read_json(folder / ".zattrs");
  } else if (exists_entry(folder / "zarr.json")) {
    const json j = read_json(folder / "zarr.json");
    attrs = j.contains("attributes") ? j["attributes"] : json::object();
    if (attrs.contains("ome")) {
      version = attrs["ome"].value("version", std::string("0.5"));
      attrs = attrs["ome"];
    }
  }
  if (!attrs.is_object() || !attrs.contains("multiscales") || !attrs["multiscales"].is_array() ||
      attrs["multiscales"].empty()) {
    return {json(), ""};
  }
  const json ms = attrs["multiscales"][0];
  if (version.empty()) version = ms.value("version", std::string("0.4"));
  return {ms, version};
}

double unit_to_um(const std::string& unit, const fs::path& file) {
  static const std::pair<const char*, double> kUnits[] = {
      {"", 1.0},          {"micrometer", 1.0}, {"micron", 1.0},   {"um", 1.0},         {"nanometer", 1e-3},
      {"nm", 1e-3},       {"angstrom", 1e-4},  {"picometer", 1e-6}, {"millimeter", 1e3}, {"mm", 1e3},
      {"centimeter", 1e4}, {"meter", 1e6}};
  for (const auto& [n, f] : kUnits) {
    if (unit == n) return f;
  }
  fail_input(file, "axis unit \"" + unit + "\" is not a length hisnegs converts to µm");
}

// Axis letters (t, c, z, y, x) and each axis' µm per unit, from OME axes (objects
// or, as v0.3, names).
std::pair<std::string, std::vector<double>> axes_of(const json& ms, std::size_t ndim, const fs::path& file) {
  std::string letters;
  std::vector<double> um;
  if (ms.is_object() && ms.contains("axes")) {
    for (const json& ax : ms["axes"]) {
      const std::string name = ax.is_string() ? ax.get<std::string>() : ax.value("name", std::string());
      const std::string type = ax.is_object() ? ax.value("type", std::string()) : std::string();
      const std::string unit = ax.is_object() ? ax.value("unit", std::string()) : std::string();
      char l = name.size() == 1 ? static_cast<char>(std::tolower(name[0])) : '?';
      if (type == "time") l = 't';
      if (type == "channel") l = 'c';
      if (std::string("tczyx").find(l) == std::string::npos) l = '?';
      letters += l;
      um.push_back(l == 'x' || l == 'y' || l == 'z' ? unit_to_um(unit, file) : 1.0);
    }
    if (letters.size() != ndim) fail_input(file, "multiscales axes name " + std::to_string(letters.size()) + " axes, the array has " + std::to_string(ndim));
  } else {
    static const char* kByRank[] = {"", "", "", "zyx", "czyx", "tczyx"};
    if (ndim < 3) fail_input(file, "has " + std::to_string(ndim) + " axes; a 3D stack (z, y, x) is read");
    letters = kByRank[ndim];
    um.assign(ndim, 1.0);
  }
  for (const char l : std::string("zyx")) {
    if (std::count(letters.begin(), letters.end(), l) != 1) fail_input(file, "axes \"" + letters + "\" do not name x, y and z once each");
  }
  return {letters, um};
}

// The product of the `scale` transformations of a list (identity when none).
std::vector<double> scale_of(const json& list, std::size_t ndim, const fs::path& file) {
  std::vector<double> s(ndim, 1.0);
  if (!list.is_array()) return s;
  for (const json& t : list) {
    if (t.value("type", std::string()) != "scale") continue;
    const auto v = field<std::vector<double>>(t, "scale", file);
    if (v.size() != ndim) fail_input(file, "a scale has " + std::to_string(v.size()) + " values for " + std::to_string(ndim) + " axes");
    for (std::size_t d = 0; d < ndim; ++d) s[d] *= v[d];
  }
  return s;
}

fs::path metadata_file(const fs::path& folder) {
  return exists_entry(folder / ".zattrs") ? folder / ".zattrs" : exists_entry(folder / "zarr.json") ? folder / "zarr.json" : folder / ".zgroup";
}

void check_dataset_path(const std::string& p, const fs::path& file) {
  const fs::path rel(p);
  if (p.empty() || rel.is_absolute() ||
      std::any_of(rel.begin(), rel.end(), [](const fs::path& e) { return e == ".." || e == "."; })) {
    fail_input(file, "dataset path \"" + p + "\" leaves the folder or is empty");
  }
}

ZarrLevel level_of(const Array& a, const std::string& path, const std::array<double, 3>& scale) {
  ZarrLevel l;
  l.path = path;
  l.shape = a.shape;
  l.chunks = a.chain.sharding ? a.chain.sharding->inner : a.chunk;
  l.codecs = a.chain.describe();
  l.scale_um = scale;
  return l;
}


// Fixes t and c, the sizes and the sample type from the array, checking the choices.
void choose_indices(ZarrStackInfo& info, const Array& a, const ZarrReadOptions& options) {
  const fs::path& p = info.named;
  for (std::size_t d = 0; d < info.axes.size(); ++d) {
    const char l = info.axes[d];
    const long long n = a.shape[d];
    if (l == 'x') info.nx = static_cast<int>(n);
    if (l == 'y') info.ny = static_cast<int>(n);
    if (l == 'z') info.nz = static_cast<int>(n);
    if (l == 't' || l == 'c' || l == '?') {
      const std::optional<int>& chosen = l == 't' ? options.timepoint : options.channel;
      const char* what = l == 't' ? "time points" : l == 'c' ? "channels" : "values along a custom axis";
      const char* option = l == 't' ? "--timepoint" : "--channel";
      if (l == 't') info.timepoints = static_cast<int>(n);
      if (l == 'c') info.channels = static_cast<int>(n);
      long long index = 0;
      if (l == '?') {
        if (n != 1) fail_input(p, "has an axis of " + std::to_string(n) + " " + what + " that is not t, c, z, y or x");
      } else if (chosen) {
        if (*chosen < 0 || *chosen >= n) fail_input(p, option + std::string(" ") + std::to_string(*chosen) + " is out of range: it has " + std::to_string(n) + " " + what + " (0.." + std::to_string(n - 1) + ")");
        index = *chosen;
      } else if (n > 1) {
        fail_input(p, "has " + std::to_string(n) + " " + what + "; choose one with " + option + " (0.." + std::to_string(n - 1) + ")");
      }
      if (l == 't') info.time_index = index;
      if (l == 'c' || l == '?') info.channel_index = l == 'c' ? index : info.channel_index;
    }
  }
  if (options.channel && info.axes.find('c') == std::string::npos && *options.channel != 0) {
    fail_input(p, "--channel " + std::to_string(*options.channel) + ": the array has no channel axis");
  }
  if (options.timepoint && info.axes.find('t') == std::string::npos && *options.timepoint != 0) {
    fail_input(p, "--timepoint " + std::to_string(*options.timepoint) + ": the array has no time axis");
  }
  if (info.nz < 2) fail_input(p, "has a single Z slice; expected a 3D stack");
  info.type = a.kind == 'u' ? (a.size == 1 ? SampleType::kUint8 : SampleType::kUint16) : SampleType::kFloat32;
  info.dtype = type_name(a);
}

}  // namespace

bool is_zarr_stack(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_directory(path, ec)) return false;
  static const char* const kMetadata[] = {".zarray", ".zgroup", ".zattrs", "zarr.json"};
  return std::any_of(std::begin(kMetadata), std::end(kMetadata), [&](const char* f) { return exists_entry(path / f); });
}

namespace {

// Where the array to read is: the folder itself (a bare array, maybe one level of
// a multiscale group above it) or the chosen level of the multiscale group.
// (clang-tidy sees a throwing implicit member through json's members; nothing here throws.)
struct Located {  // NOLINT(bugprone-exception-escape)
  std::optional<Array> array;
  json ms;           // the OME multiscales entry (null: none)
  fs::path ms_file;  // the file it came from
  std::string level_path;
  bool group = false;  // the folder named is the multiscale group (or holds it, bioformats2raw)
  fs::path group_folder;  // the multiscale group's folder
};

// bioformats2raw's layout: a group marked "bioformats2raw.layout" whose image 0
// (folder "0") is the multiscale group.
bool is_bioformats2raw(const fs::path& folder) {
  if (!exists_entry(folder / ".zattrs") && !exists_entry(folder / "zarr.json")) return false;
  json attrs = read_json(exists_entry(folder / ".zattrs") ? folder / ".zattrs" : folder / "zarr.json");
  if (attrs.contains("attributes") && attrs["attributes"].is_object()) attrs = attrs["attributes"];
  if (attrs.contains("ome") && attrs["ome"].is_object()) attrs = attrs["ome"];
  return attrs.is_object() && attrs.contains("bioformats2raw.layout");
}

Located locate(const fs::path& path, const ZarrReadOptions& options, ZarrStackInfo& info) {
  Located at;
  at.array = array_in(path);
  if (at.array) {
    // A bare array, maybe one level of a multiscale group: its scale from the parent.
    const fs::path self = path.has_filename() ? path : path.parent_path();
    const fs::path parent = self.parent_path();
    auto [pms, version] = multiscales_of(parent);
    at.level_path = self.filename().string();
    if (pms.is_object() && pms.contains("datasets") && pms["datasets"].is_array()) {
      for (std::size_t i = 0; i < pms["datasets"].size(); ++i) {
        if (pms["datasets"][i].is_object() && pms["datasets"][i].value("path", std::string()) == at.level_path) {
          at.ms = pms;
          at.ms_file = metadata_file(parent);
          info.ome_version = version;
          info.level = static_cast<int>(i);
        }
      }
    }
    if (options.level != 0) {
      fail_input(path, "--level " + std::to_string(options.level) +
                           ": this is one array (name the multiscale group to choose a level)");
    }
    return at;
  }
  fs::path group = path;
  auto [pms, version] = multiscales_of(group);
  if (!pms.is_object() && is_bioformats2raw(path) && exists_entry(path / "0")) {
    group = path / "0";
    std::tie(pms, version) = multiscales_of(group);
  }
  if (!pms.is_object()) fail_input(path, "is a Zarr group without OME multiscales metadata; name the array folder to read");
  at.ms = pms;
  at.ms_file = metadata_file(group);
  at.group = true;
  at.group_folder = group;
  info.ome_version = version;
  const json datasets = field<json>(at.ms, "datasets", at.ms_file);
  if (!datasets.is_array() || datasets.empty()) fail_input(at.ms_file, "multiscales lists no datasets");
  const auto levels = static_cast<int>(datasets.size());
  if (options.level < 0 || options.level >= levels) {
    fail_input(path, "--level " + std::to_string(options.level) + " is out of range: it has " + std::to_string(levels) +
                         " levels (0.." + std::to_string(levels - 1) + ")");
  }
  info.level = options.level;
  for (const json& d : datasets) check_dataset_path(field<std::string>(d, "path", at.ms_file), at.ms_file);
  at.level_path = field<std::string>(datasets[static_cast<std::size_t>(options.level)], "path", at.ms_file);
  at.array = array_in(group / at.level_path);
  if (!at.array) fail_input(group / at.level_path, "holds no Zarr array (.zarray or zarr.json)");
  return at;
}

// Every level's shape, chunks, codecs and voxel size (µm, x y z), in the order listed.
void read_pyramid(ZarrStackInfo& info, const Located& at, const fs::path& path) {
  const std::size_t ndim = at.array->shape.size();
  const auto axes = axes_of(at.ms, ndim, at.ms_file.empty() ? path : at.ms_file);
  info.axes = axes.first;
  const std::vector<double>& unit_um = axes.second;
  const std::vector<double> global = at.ms.is_object()
                                         ? scale_of(at.ms.value("coordinateTransformations", json()), ndim, at.ms_file)
                                         : std::vector<double>(ndim, 1.0);
  const auto spatial = [&](const json& dataset) {
    const std::vector<double> s = scale_of(dataset.value("coordinateTransformations", json()), ndim, at.ms_file);
    std::array<double, 3> um{1, 1, 1};
    for (std::size_t d = 0; d < ndim; ++d) {
      const auto a = std::string("xyz").find(info.axes[d]);
      if (a != std::string::npos) um[a] = s[d] * global[d] * unit_um[d];
    }
    return um;
  };
  if (!at.group) {
    const std::array<double, 3> um =
        at.ms.is_object() ? spatial(at.ms["datasets"][static_cast<std::size_t>(info.level)]) : std::array<double, 3>{1, 1, 1};
    info.pyramid.push_back(level_of(*at.array, at.level_path, um));
    return;
  }
  for (const json& d : at.ms["datasets"]) {
    const std::string p = d.value("path", std::string());
    if (p == at.level_path) {
      info.pyramid.push_back(level_of(*at.array, p, spatial(d)));
    } else if (const std::optional<Array> other = array_in(at.group_folder / p)) {
      info.pyramid.push_back(level_of(*other, p, spatial(d)));
    } else {
      fail_input(at.group_folder / p, "holds no Zarr array (.zarray or zarr.json), a level its multiscales lists");
    }
  }
}

void set_spacing(ZarrStackInfo& info, const Located& at, const ZarrReadOptions& options) {
  const ZarrLevel& chosen = info.pyramid[at.group ? static_cast<std::size_t>(info.level) : 0];
  for (int a = 0; a < 3; ++a) {
    if (options.spacing_um) {
      info.spacing.um[a] = (*options.spacing_um)[a];
      info.spacing.source[a] = SpacingSource::kUser;
    } else if (at.ms.is_object()) {
      const std::string problem = voxel_size_problem(chosen.scale_um[a]);
      if (!problem.empty()) {
        fail_input(at.ms_file, std::string("the ") + "xyz"[a] + " scale of level " + std::to_string(info.level) +
                                   " is " + number_text(chosen.scale_um[a]) + " um: " + problem);
      }
      info.spacing.um[a] = chosen.scale_um[a];
      info.spacing.source[a] = SpacingSource::kOmeZarr;
    }
  }
}

}  // namespace

namespace {
ZarrStackInfo inspect_checked(const fs::path& path, const ZarrReadOptions& options);
}  // namespace

ZarrStackInfo inspect_zarr_stack(const fs::path& path, const ZarrReadOptions& options) {
  if (!is_zarr_stack(path)) fail_input(path, "is not a Zarr folder (no .zarray, .zgroup, .zattrs or zarr.json)");
  // Every field is checked where it is read; a value of an unexpected JSON type met
  // anywhere else (an "order" that is a list, a dataset that is a number) is the
  // metadata's fault too, said in one line.
  try {
    return inspect_checked(path, options);
  } catch (const json::exception& e) {
    fail_input(path, std::string("has malformed metadata: ") + e.what());
  }
}

namespace {

ZarrStackInfo inspect_checked(const fs::path& path, const ZarrReadOptions& options) {
  ZarrStackInfo info;
  info.named = path;
  Located at = locate(path, options, info);
  info.array = at.array->folder;
  info.zarr_format = at.array->format;
  read_pyramid(info, at, path);
  choose_indices(info, *at.array, options);
  set_spacing(info, at, options);
  const std::vector<long long>& unit = at.array->chain.sharding ? at.array->chain.sharding->inner : at.array->chunk;
  double chunk_values = 1;
  for (const long long e : unit) chunk_values *= static_cast<double>(e);
  if (chunk_values > static_cast<double>(kMaxChunkValues)) {
    fail_input(info.array, "a chunk of " + joined_extents(unit) + " values is over the 2^28 hisnegs decodes at once");
  }
  info.plan = std::make_shared<const Array>(std::move(*at.array));
  return info;
}

}  // namespace

std::string ZarrStackInfo::describe() const {
  std::string s = ome_version.empty() ? "Zarr v" + std::to_string(zarr_format) + " array"
                                      : "OME-Zarr v" + ome_version + " (Zarr v" + std::to_string(zarr_format) + ")";
  if (pyramid.size() > 1 || !ome_version.empty()) {
    s += ", level " + std::to_string(level) + " of " + std::to_string(std::max<std::size_t>(pyramid.size(), 1));
  }
  const ZarrLevel& l = pyramid.size() > static_cast<std::size_t>(level) ? pyramid[static_cast<std::size_t>(level)] : pyramid.front();
  s += ", " + dtype + ", axes " + axes + ", chunks " + joined_extents(l.chunks) + ", " + l.codecs;
  if (channels > 1) s += ", " + std::to_string(channels) + " channels";
  if (timepoints > 1) s += ", " + std::to_string(timepoints) + " time points";
  return s;
}

namespace {

// The bytes [offset, offset + count) of a chunk or shard file (count -1: all).
// The largest encoded size of a chunk of `expected` bytes through `chain`: what the
// compressors' own bounds allow (blosc, zstd and deflate store incompressible data
// with a small overhead) and 4 bytes per CRC-32C; a longer file is refused before
// anything is allocated for it.
long long encoded_bound(const Chain& chain, std::size_t expected) {
  long long bound = static_cast<long long>(expected);
  for (const ByteCodec& c : chain.bytes) {
    bound += c.kind == ByteCodec::Kind::kCrc32c ? 4 : static_cast<long long>(expected / 8) + (64 << 10);
  }
  return bound;
}

std::vector<std::uint8_t> read_bytes(const fs::path& file, long long offset, long long count, long long bound) {
  const int fd = open_regular_file(file);
  struct stat st {};
  ::fstat(fd, &st);
  if (count < 0) count = st.st_size - offset;
  if (count > bound) {
    ::close(fd);
    fail_input(file, "holds " + std::to_string(count) + " bytes for a chunk; at most " + std::to_string(bound) +
                         " can encode it");
  }
  if (offset < 0 || count < 0 || offset + count > st.st_size) {
    ::close(fd);
    fail_input(file, "bytes " + std::to_string(offset) + ".." + std::to_string(offset + count) + " lie past its end (" + std::to_string(st.st_size) + " bytes)");
  }
  std::vector<std::uint8_t> out(static_cast<std::size_t>(count));
  std::size_t done = 0;
  while (done < out.size()) {
    const ssize_t n = ::pread(fd, out.data() + done, out.size() - done, static_cast<off_t>(offset + static_cast<long long>(done)));
    if (n <= 0) {
      ::close(fd);
      fail_input(file, "cannot be read");
    }
    done += static_cast<std::size_t>(n);
  }
  ::close(fd);
  return out;
}

long long product(const std::vector<long long>& v) {
  return std::accumulate(v.begin(), v.end(), 1LL, std::multiplies<>());
}

// A decoded chunk: its values as stored (native byte order), or as floats when a
// transpose had to reorder them; nothing at all for a chunk never written.
struct BlockValues {
  std::vector<std::uint8_t> bytes;
  std::vector<float> floats;
  char kind = 'u';
  int size = 2;
  float fill = 0.0f;
  bool empty = true;

  // Values [src, src + n) of the chunk (C order) into dst[0], dst[stride], ...
  void run(long long src, long long n, float* dst, long long stride) const {
    const auto put = [&](auto value_at) {
      if (stride == 1) {
        for (long long i = 0; i < n; ++i) dst[i] = value_at(src + i);
      } else {
        for (long long i = 0; i < n; ++i) dst[i * stride] = value_at(src + i);
      }
    };
    const std::uint8_t* p = bytes.data();
    if (empty) {
      put([&](long long) { return fill; });
    } else if (!floats.empty()) {
      put([&](long long i) { return floats[static_cast<std::size_t>(i)]; });
    } else if (size == 1) {
      put([&](long long i) { return static_cast<float>(p[i]); });
    } else if (size == 2 && kind == 'u') {
      put([&](long long i) {
        std::uint16_t v = 0;
        std::memcpy(&v, p + 2 * i, 2);
        return static_cast<float>(v);
      });
    } else if (size == 2) {
      put([&](long long i) {
        std::int16_t v = 0;
        std::memcpy(&v, p + 2 * i, 2);
        return static_cast<float>(v);
      });
    } else {
      put([&](long long i) {
        float v = 0;
        std::memcpy(&v, p + 4 * i, 4);
        return v;
      });
    }
  }
};

BlockValues fill_block(const Array& a) {
  BlockValues v;
  v.fill = a.fill;
  return v;
}

// The values of the transposed chunk `v` (bytes) as floats in the decoded order.
void undo_transposes(const Chain& chain, const std::vector<long long>& shape, BlockValues& v) {
  const std::size_t count = static_cast<std::size_t>(product(shape));
  std::vector<float> values(count);
  v.run(0, static_cast<long long>(count), values.data(), 1);
  // The encoded array's dim k is the decoded dim order[k]; undone last first.
  std::vector<std::vector<long long>> shapes{shape};
  for (const auto& order : chain.transposes) {
    std::vector<long long> e(order.size());
    for (std::size_t k = 0; k < order.size(); ++k) e[k] = shapes.back()[static_cast<std::size_t>(order[k])];
    shapes.push_back(e);
  }
  for (std::size_t t = chain.transposes.size(); t-- > 0;) {
    const auto& order = chain.transposes[t];
    const std::vector<long long>& dec = shapes[t];
    const std::vector<long long>& enc = shapes[t + 1];
    const std::size_t nd = dec.size();
    std::vector<long long> enc_stride(nd, 1), stride_in_dec(nd, 0);
    for (std::size_t k = nd - 1; k > 0; --k) enc_stride[k - 1] = enc_stride[k] * enc[k];
    for (std::size_t k = 0; k < nd; ++k) stride_in_dec[static_cast<std::size_t>(order[k])] = enc_stride[k];
    std::vector<float> out(values.size());
    std::vector<long long> idx(nd, 0);
    for (std::size_t i = 0; i < out.size(); ++i) {
      long long src = 0;
      for (std::size_t d = 0; d < nd; ++d) src += idx[d] * stride_in_dec[d];
      out[i] = values[static_cast<std::size_t>(src)];
      for (std::size_t d = nd; d-- > 0;) {
        if (++idx[d] < dec[d]) break;
        idx[d] = 0;
      }
    }
    values.swap(out);
  }
  v.floats = std::move(values);
  v.bytes.clear();
}

// bytes -> the chunk's values (C order of `shape`): the byte codecs undone, the
// byte order made native, the transposes undone.
BlockValues decode_chunk(const Chain& chain, std::vector<std::uint8_t> bytes, const std::vector<long long>& shape,
                         const Array& a, const fs::path& file) {
  const long long n = product(shape);
  const std::size_t expected = static_cast<std::size_t>(n) * static_cast<std::size_t>(a.size);
  try {
    for (auto c = chain.bytes.rbegin(); c != chain.bytes.rend(); ++c) {
      // A compressor (there is at most one) gives the chunk plus the checksums of
      // the codecs still to undo after it.
      const auto checksums_inside = std::count_if(std::next(c), chain.bytes.rend(), [](const ByteCodec& b) {
        return b.kind == ByteCodec::Kind::kCrc32c;
      });
      const std::size_t want = c->kind == ByteCodec::Kind::kCrc32c ? bytes.size() - std::min<std::size_t>(4, bytes.size())
                                                                   : expected + 4 * static_cast<std::size_t>(checksums_inside);
      bytes = zarr::decode(*c, bytes, want);
    }
  } catch (const std::runtime_error& e) {
    fail_input(file, e.what());
  }
  if (bytes.size() != expected) {
    fail_input(file, "holds " + std::to_string(bytes.size()) + " bytes, the chunk " + std::to_string(expected));
  }
  if (chain.big_endian && a.size > 1) {
    for (std::size_t i = 0; i < bytes.size(); i += static_cast<std::size_t>(a.size)) {
      std::reverse(bytes.begin() + static_cast<std::ptrdiff_t>(i), bytes.begin() + static_cast<std::ptrdiff_t>(i) + a.size);
    }
  }
  BlockValues v;
  v.bytes = std::move(bytes);
  v.kind = a.kind;
  v.size = a.size;
  v.fill = a.fill;
  v.empty = false;
  if (!chain.transposes.empty()) undo_transposes(chain, shape, v);
  return v;
}

// Where the region lies in array coordinates, and each array axis' stride in `out`.
struct Region {
  std::vector<long long> lo, hi, out_stride;
};

Region region_of(const ZarrStackInfo& info, const std::array<int, 3>& lo, const std::array<int, 3>& hi) {
  Region r;
  const long long w = hi[0] - lo[0], h = hi[1] - lo[1];
  for (const char l : info.axes) {
    const auto at = std::string("xyz").find(l);
    if (at != std::string::npos) {
      r.lo.push_back(lo[at]);
      r.hi.push_back(hi[at]);
      r.out_stride.push_back(at == 0 ? 1 : at == 1 ? w : w * h);
    } else {
      const long long i = l == 't' ? info.time_index : l == 'c' ? info.channel_index : 0;
      r.lo.push_back(std::max(0LL, i));
      r.hi.push_back(std::max(0LL, i) + 1);
      r.out_stride.push_back(0);
    }
  }
  return r;
}

// Copies the part of a block (origin, shape, C order) inside the region into `out`.
void copy_block(const BlockValues& values, const std::vector<long long>& origin, const std::vector<long long>& shape,
                const Region& r, float* out) {
  const std::size_t nd = shape.size();
  std::vector<long long> a(nd), b(nd), stride(nd, 1);
  for (std::size_t d = nd - 1; d > 0; --d) stride[d - 1] = stride[d] * shape[d];
  for (std::size_t d = 0; d < nd; ++d) {
    a[d] = std::max(origin[d], r.lo[d]);
    b[d] = std::min(origin[d] + shape[d], r.hi[d]);
    if (a[d] >= b[d]) return;
  }
  std::vector<long long> idx = a;
  const std::size_t last = nd - 1;
  while (true) {
    long long src = 0, dst = 0;
    for (std::size_t d = 0; d < last; ++d) {
      src += (idx[d] - origin[d]) * stride[d];
      dst += (idx[d] - r.lo[d]) * r.out_stride[d];
    }
    src += a[last] - origin[last];
    dst += (a[last] - r.lo[last]) * r.out_stride[last];
    values.run(src, b[last] - a[last], out + dst, r.out_stride[last]);
    std::size_t d = last;
    while (d-- > 0) {
      if (++idx[d] < b[d]) break;
      idx[d] = a[d];
    }
    if (d == static_cast<std::size_t>(-1)) return;
  }
}

// Calls fn(grid index, origin) for every block of `block` shape over [lo, hi)
// within [origin0, origin0 + extent).
void for_blocks(const std::vector<long long>& lo, const std::vector<long long>& hi, const std::vector<long long>& origin0,
                const std::vector<long long>& block,
                const std::function<void(const std::vector<long long>&, const std::vector<long long>&)>& fn) {
  const std::size_t nd = block.size();
  std::vector<long long> first(nd), last(nd);
  for (std::size_t d = 0; d < nd; ++d) {
    first[d] = (std::max(lo[d], origin0[d]) - origin0[d]) / block[d];
    last[d] = (hi[d] - 1 - origin0[d]) / block[d];
    if (hi[d] <= origin0[d] || first[d] > last[d]) return;
  }
  std::vector<long long> idx = first, at(nd);
  while (true) {
    for (std::size_t d = 0; d < nd; ++d) at[d] = origin0[d] + idx[d] * block[d];
    fn(idx, at);
    std::size_t d = nd;
    while (d-- > 0) {
      if (++idx[d] <= last[d]) break;
      idx[d] = first[d];
    }
    if (d == static_cast<std::size_t>(-1)) return;
  }
}

void read_shard(const Array& a, const fs::path& file, const std::vector<long long>& origin, const Region& r,
                const std::vector<long long>& hi, float* out) {
  const zarr::Sharding& s = *a.chain.sharding;
  const std::size_t nd = a.chunk.size();
  std::vector<long long> per(nd);
  for (std::size_t d = 0; d < nd; ++d) per[d] = a.chunk[d] / s.inner[d];
  const long long n = product(per);
  long long index_bytes = 16 * n;
  for (const ByteCodec& c : s.index.bytes) {
    if (c.kind != ByteCodec::Kind::kCrc32c) fail_input(a.folder / "zarr.json", "the shard index has a compressor; only bytes and crc32c are read");
    index_bytes += 4;
  }
  struct stat st {};
  if (::stat(file.c_str(), &st) != 0 || st.st_size < index_bytes) fail_input(file, "is shorter than its shard index (" + std::to_string(index_bytes) + " bytes)");
  std::vector<std::uint8_t> raw = read_bytes(file, s.index_at_end ? st.st_size - index_bytes : 0, index_bytes, index_bytes);
  try {
    for (auto c = s.index.bytes.rbegin(); c != s.index.bytes.rend(); ++c) raw = zarr::decode(*c, raw, raw.size() - 4);
  } catch (const std::runtime_error& e) {
    fail_input(file, std::string("shard index: ") + e.what());
  }
  auto u64 = [&](std::size_t i) {
    std::uint64_t v = 0;
    for (int k = 0; k < 8; ++k) {
      const std::size_t at = i * 8 + static_cast<std::size_t>(s.index.big_endian ? 7 - k : k);
      v |= static_cast<std::uint64_t>(raw[at]) << (8 * k);
    }
    return v;
  };
  std::vector<long long> inside = hi;  // the region within this shard
  for (std::size_t d = 0; d < nd; ++d) inside[d] = std::min(hi[d], origin[d] + a.chunk[d]);
  for_blocks(r.lo, inside, origin, s.inner, [&](const std::vector<long long>& idx, const std::vector<long long>& at) {
    long long linear = 0;
    for (std::size_t d = 0; d < nd; ++d) linear = linear * per[d] + idx[d];
    const std::uint64_t offset = u64(2 * static_cast<std::size_t>(linear)), nbytes = u64(2 * static_cast<std::size_t>(linear) + 1);
    if (offset == ~0ULL && nbytes == ~0ULL) {
      copy_block(fill_block(a), at, s.inner, r, out);
      return;
    }
    if (offset > static_cast<std::uint64_t>(st.st_size) || nbytes > static_cast<std::uint64_t>(st.st_size) - offset) {
      fail_input(file, "shard index entry " + std::to_string(linear) + " lies past the file's end");
    }
    copy_block(decode_chunk(s.chain, read_bytes(file, static_cast<long long>(offset), static_cast<long long>(nbytes),
                                       encoded_bound(s.chain, static_cast<std::size_t>(product(s.inner)) * static_cast<std::size_t>(a.size))),
                            s.inner, a, file),
               at, s.inner, r, out);
  });
}

}  // namespace

void read_zarr_region(const ZarrStackInfo& info, const std::array<int, 3>& lo, const std::array<int, 3>& hi, float* out) {
  const Array& a = *info.plan;
  const Region r = region_of(info, lo, hi);
  const std::vector<long long> zero(a.chunk.size(), 0);
  for_blocks(r.lo, r.hi, zero, a.chunk, [&](const std::vector<long long>& idx, const std::vector<long long>& at) {
    const fs::path file = a.chunk_path(idx);
    if (!exists_entry(file)) {
      copy_block(fill_block(a), at, a.chunk, r, out);
    } else if (a.chain.sharding) {
      read_shard(a, file, at, r, r.hi, out);
    } else {
      copy_block(decode_chunk(a.chain,
                              read_bytes(file, 0, -1,
                                         encoded_bound(a.chain, static_cast<std::size_t>(product(a.chunk)) *
                                                                    static_cast<std::size_t>(a.size))),
                              a.chunk, a, file), at, a.chunk, r, out);
    }
  });
}

namespace {

// A level named alone takes its axes and scale from the group above it: that
// group's metadata file is part of what the stack is.
void add_group_metadata(const fs::path& path, std::vector<fs::path>& files) {
  const fs::path self = path.has_filename() ? path : path.parent_path();
  if (!array_in_folder(self)) return;
  for (const char* name : {".zattrs", "zarr.json"}) {
    const fs::path above = self.parent_path() / name;
    if (exists_entry(above)) files.push_back(above);
  }
}

}  // namespace

std::vector<fs::path> zarr_stack_files(const fs::path& path) {
  std::vector<fs::path> files{path};
  try {
    add_group_metadata(path, files);
  } catch (const std::exception&) {  // never throws: the reader reports what is wrong
  }
  return files;
}

}  // namespace hisnegs::io

namespace hisnegs::io {
namespace {

// A file inside the writer's temp folder (the folder is renamed into place whole).
void put_file(const fs::path& file, const void* data, std::size_t size) {
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out.write(static_cast<const char*>(data), static_cast<std::streamsize>(size));
  out.close();
  if (!out) throw WriteError(describe(file, "cannot write"));
}
void put_file(const fs::path& file, const std::string& text) { put_file(file, text.data(), text.size()); }

// The next level down: x and y halved (ceil), z too when `halve_z`, each voxel the
// mean of the block it stands for (edge blocks: of the voxels they hold).
Volume halved(const Volume& v, bool halve_z) {
  Volume h;
  h.nx = (v.nx + 1) / 2;
  h.ny = (v.ny + 1) / 2;
  h.nz = halve_z ? (v.nz + 1) / 2 : v.nz;
  h.voxels.assign(static_cast<std::size_t>(h.nx) * static_cast<std::size_t>(h.ny) * static_cast<std::size_t>(h.nz), 0.0f);
  const int fz = halve_z ? 2 : 1;
  for (int z = 0; z < h.nz; ++z) {
    for (int y = 0; y < h.ny; ++y) {
      for (int x = 0; x < h.nx; ++x) {
        double sum = 0.0;
        int n = 0;
        for (int dz = 0; dz < fz && z * fz + dz < v.nz; ++dz) {
          for (int dy = 0; dy < 2 && 2 * y + dy < v.ny; ++dy) {
            for (int dx = 0; dx < 2 && 2 * x + dx < v.nx; ++dx) {
              sum += v.voxels[v.index(2 * x + dx, 2 * y + dy, z * fz + dz)];
              ++n;
            }
          }
        }
        h.voxels[h.index(x, y, z)] = static_cast<float>(sum / n);
      }
    }
  }
  h.spacing = v.spacing;
  h.spacing.um[0] = v.spacing.um[0] * 2.0;
  h.spacing.um[1] = v.spacing.um[1] * 2.0;
  h.spacing.um[2] = v.spacing.um[2] * (halve_z ? 2.0 : 1.0);
  return h;
}

// One level's array: .zarray and its chunks (z/y/x keys), every chunk full size.
void write_level(const fs::path& folder, const Volume& v, const ZarrWriteOptions& o) {
  fs::create_directories(folder);
  const int e = o.chunk_edge;
  const std::array<int, 3> chunk{std::min(e, v.nx), std::min(e, v.ny), std::min(e, v.nz)};
  const int size = o.type == SampleType::kUint8 ? 1 : o.type == SampleType::kUint16 ? 2 : 4;
  const char* dtype = o.type == SampleType::kUint8 ? "|u1" : o.type == SampleType::kUint16 ? "<u2" : "<f4";
  const json meta = {{"zarr_format", 2},
                     {"shape", {v.nz, v.ny, v.nx}},
                     {"chunks", {chunk[2], chunk[1], chunk[0]}},
                     {"dtype", dtype},
                     {"compressor", {{"id", "blosc"}, {"cname", "zstd"}, {"clevel", o.zstd_level}, {"shuffle", 1}, {"blocksize", 0}}},
                     {"fill_value", 0},
                     {"order", "C"},
                     {"filters", nullptr},
                     {"dimension_separator", "/"}};
  put_file(folder / ".zarray", meta.dump(2) + "\n");
  ByteCodec codec;
  codec.kind = ByteCodec::Kind::kBlosc;
  codec.level = o.zstd_level;
  codec.typesize = static_cast<std::size_t>(size);
  const float top = o.type == SampleType::kUint8 ? 255.0f : 65535.0f;
  std::vector<std::uint8_t> bytes(static_cast<std::size_t>(chunk[0]) * chunk[1] * chunk[2] * size);
  for (int cz = 0; cz * chunk[2] < v.nz; ++cz) {
    for (int cy = 0; cy * chunk[1] < v.ny; ++cy) {
      for (int cx = 0; cx * chunk[0] < v.nx; ++cx) {
        std::fill(bytes.begin(), bytes.end(), std::uint8_t{0});
        std::size_t i = 0;
        for (int z = cz * chunk[2]; z < (cz + 1) * chunk[2]; ++z) {
          for (int y = cy * chunk[1]; y < (cy + 1) * chunk[1]; ++y) {
            for (int x = cx * chunk[0]; x < (cx + 1) * chunk[0]; ++x, i += static_cast<std::size_t>(size)) {
              if (x >= v.nx || y >= v.ny || z >= v.nz) continue;
              const float f = v.voxels[v.index(x, y, z)];
              if (size == 4) {
                std::memcpy(&bytes[i], &f, 4);
              } else {
                const auto q = static_cast<std::uint16_t>(std::lround(std::clamp(f, 0.0f, top)));
                bytes[i] = static_cast<std::uint8_t>(q & 0xFF);
                if (size == 2) bytes[i + 1] = static_cast<std::uint8_t>(q >> 8);
              }
            }
          }
        }
        const fs::path file = folder / std::to_string(cz) / std::to_string(cy) / std::to_string(cx);
        fs::create_directories(file.parent_path());
        const std::vector<std::uint8_t> packed = zarr::encode(codec, bytes);
        put_file(file, packed.data(), packed.size());
      }
    }
  }
}

}  // namespace

void write_ome_zarr(const fs::path& path, const Volume& volume, const ZarrWriteOptions& options) {
  if (options.chunk_edge < 8 || options.chunk_edge > 1024) throw std::invalid_argument("write_ome_zarr: chunk_edge out of [8, 1024]");
  std::error_code ec;
  const auto st = fs::symlink_status(path, ec);
  const bool replacing = fs::exists(st);
  if (replacing && !(fs::is_directory(st) && is_zarr_stack(path))) {
    fail_input(path, "exists and is not a Zarr folder; refusing to replace it");
  }
  std::random_device rd;
  const fs::path temp = path.parent_path() / (path.filename().string() + ".tmp-" + std::to_string(rd()));
  try {
    fs::create_directories(temp);
    put_file(temp / ".zgroup", json{{"zarr_format", 2}}.dump() + "\n");
    json datasets = json::array();
    Volume level = volume;
    for (int l = 0; l < options.max_levels; ++l) {
      write_level(temp / std::to_string(l), level, options);
      datasets.push_back({{"path", std::to_string(l)},
                          {"coordinateTransformations",
                           {{{"type", "scale"}, {"scale", {level.spacing.um[2], level.spacing.um[1], level.spacing.um[0]}}}}}});
      if (std::max(level.nx, level.ny) / 2 < options.min_edge) break;
      const double xy_after = 2.0 * std::max(level.spacing.um[0], level.spacing.um[1]);
      level = halved(level, level.spacing.um[2] * std::sqrt(2.0) < xy_after && level.nz >= 2 * 2);
    }
    const json axes = {{{"name", "z"}, {"type", "space"}, {"unit", "micrometer"}},
                       {{"name", "y"}, {"type", "space"}, {"unit", "micrometer"}},
                       {{"name", "x"}, {"type", "space"}, {"unit", "micrometer"}}};
    const json attrs = {{"multiscales",
                         {{{"version", "0.4"},
                           {"name", path.filename().string()},
                           {"axes", axes},
                           {"datasets", datasets},
                           {"type", "mean of 2x2(x2) blocks"},
                           {"metadata", {{"writer", "hisnegs"}}}}}}};
    put_file(temp / ".zattrs", attrs.dump(2) + "\n");
    if (replacing) {
      const fs::path old = path.parent_path() / (path.filename().string() + ".old-" + std::to_string(rd()));
      fs::rename(path, old);
      fs::rename(temp, path);
      fs::remove_all(old, ec);
    } else {
      fs::rename(temp, path);
    }
  } catch (...) {
    fs::remove_all(temp, ec);
    throw;
  }
}

}  // namespace hisnegs::io
