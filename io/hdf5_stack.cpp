// SPDX-License-Identifier: Apache-2.0
// HDF5 stacks on libhdf5: layout detection (plain, BigDataViewer, Imaris), metadata,
// hyperslab reads into float32, and a plain chunked writer.
#include "io/hdf5_stack.hpp"

#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <mutex>
#include <sstream>

#include "io/atomic_file.hpp"
#include "io/detail/tiff_metadata.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"

namespace hisnegs::io {
namespace {

namespace fs = std::filesystem;

// Debian's libhdf5 is built without thread safety: every call goes through this lock.
std::mutex& hdf5_mutex() {
  static std::mutex m;
  return m;
}

// libhdf5 prints its error stack to stderr unless told not to; hisnegs reports the
// innermost message in its own one-line error instead.
void silence_hdf5() {
  static const bool once = [] {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    return true;
  }();
  (void)once;
}

herr_t innermost_error(unsigned, const H5E_error2_t* e, void* data) {
  if (e->desc && *e->desc) *static_cast<std::string*>(data) = e->desc;
  return 0;
}

// libhdf5's innermost error message ("" when none).
std::string hdf5_error() {
  std::string message;
  H5Ewalk2(H5E_DEFAULT, H5E_WALK_DOWNWARD, innermost_error, &message);
  return message.empty() ? "" : " (libhdf5: " + printable(message, 160) + ")";
}

// An HDF5 identifier closed by `close` when it goes out of scope.
class Handle {
 public:
  Handle(hid_t id, herr_t (*close)(hid_t)) : id_(id), close_(close) {}
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  Handle(Handle&& o) noexcept : id_(o.id_), close_(o.close_) { o.id_ = -1; }
  ~Handle() {
    if (id_ >= 0) close_(id_);
  }
  [[nodiscard]] bool ok() const { return id_ >= 0; }
  operator hid_t() const { return id_; }  // NOLINT(google-explicit-constructor): a handle is used as its id

 private:
  hid_t id_;
  herr_t (*close_)(hid_t);
};

Handle open_file(const fs::path& path) {
  Handle f(H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT), H5Fclose);
  if (!f.ok()) fail_input(path, "not a readable HDF5 file" + hdf5_error());
  return f;
}

// The stack's dataset `name` in `file` (the file `path`), with the files an external
// or virtual dataset names resolved in the stack's own folder (not the working
// directory); check_outside_storage has checked them.
Handle open_dataset(const fs::path& path, hid_t file, const std::string& name) {
  const std::string folder = fs::absolute(path).parent_path().string();
  Handle dapl(H5Pcreate(H5P_DATASET_ACCESS), H5Pclose);
  if (dapl.ok()) {
    H5Pset_efile_prefix(dapl, folder.c_str());
    H5Pset_virtual_prefix(dapl, folder.c_str());
  }
  Handle d(H5Dopen2(file, name.c_str(), dapl.ok() ? hid_t(dapl) : H5P_DEFAULT), H5Dclose);
  if (!d.ok()) fail_input(path, "dataset " + printable(name, 120) + " cannot be opened" + hdf5_error());
  return d;
}

// External raw storage and virtual datasets read other files: a missing virtual
// source reads as the fill value, an external file may name any file
// (/etc/passwd as voxels). Each must be a regular file in the stack's own folder.
void check_outside_storage(const fs::path& path, hid_t dcpl, const std::string& dataset) {
  std::error_code ec;
  const fs::path folder = fs::weakly_canonical(fs::absolute(path).parent_path(), ec);
  const auto require_beside = [&](const std::string& name, const char* what) {
    const fs::path named = fs::path(name).is_absolute() ? fs::path(name) : folder / name;
    const std::string said = "dataset " + printable(dataset, 120) + " reads " + what + " '" + printable(name, 200) + "'";
    std::error_code e;
    if (!fs::is_regular_file(named, e)) fail_input(path, said + ", which is not a regular file (missing, a folder or a device)");
    if (fs::weakly_canonical(named, e).parent_path() != folder || e) {
      fail_input(path, said + ", which is not in the stack's own folder; hisnegs reads only files beside the stack");
    }
  };
  const int external = H5Pget_external_count(dcpl);
  for (int i = 0; i < external; ++i) {
    char name[4096] = {0};
    off_t offset = 0;
    hsize_t size = 0;
    if (H5Pget_external(dcpl, static_cast<unsigned>(i), sizeof name, name, &offset, &size) < 0) {
      fail_input(path, "dataset " + printable(dataset, 120) + ": its external storage cannot be read" + hdf5_error());
    }
    require_beside(name, "external raw storage");
  }
  if (H5Pget_layout(dcpl) != H5D_VIRTUAL) return;
  std::size_t sources = 0;
  if (H5Pget_virtual_count(dcpl, &sources) < 0) {
    fail_input(path, "dataset " + printable(dataset, 120) + ": its virtual sources cannot be read" + hdf5_error());
  }
  for (std::size_t i = 0; i < sources; ++i) {
    const ssize_t n = H5Pget_virtual_filename(dcpl, i, nullptr, 0);
    if (n < 0 || n > 4096) fail_input(path, "dataset " + printable(dataset, 120) + ": a virtual source without a file name");
    std::string name(static_cast<std::size_t>(n) + 1, '\0');
    H5Pget_virtual_filename(dcpl, i, name.data(), name.size());
    name.resize(static_cast<std::size_t>(n));
    if (name == ".") continue;  // the stack's own file
    require_beside(name, "the virtual source");
  }
}

bool link_exists(hid_t file, const std::string& path) {
  // Each component must exist before the next may be asked about.
  std::size_t pos = 0;
  while ((pos = path.find('/', pos + 1)) != std::string::npos) {
    if (H5Lexists(file, path.substr(0, pos).c_str(), H5P_DEFAULT) <= 0) return false;
  }
  return H5Lexists(file, path.c_str(), H5P_DEFAULT) > 0;
}

// Names of the links in group `group` (in name order).
std::vector<std::string> group_members(hid_t file, const std::string& group) {
  std::vector<std::string> names;
  Handle g(H5Gopen2(file, group.c_str(), H5P_DEFAULT), H5Gclose);
  if (!g.ok()) return names;
  H5Literate(
      g, H5_INDEX_NAME, H5_ITER_INC, nullptr,
      [](hid_t, const char* name, const H5L_info_t*, void* data) -> herr_t {
        static_cast<std::vector<std::string>*>(data)->emplace_back(name);
        return 0;
      },
      &names);
  return names;
}

// A string attribute (fixed-length, also Imaris' arrays of one-character strings,
// or variable-length scalar); nullopt when absent or not a string.
std::optional<std::string> string_attribute(hid_t file, const std::string& object, const char* name) {
  if (H5Aexists_by_name(file, object.c_str(), name, H5P_DEFAULT) <= 0) return std::nullopt;
  Handle a(H5Aopen_by_name(file, object.c_str(), name, H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
  if (!a.ok()) return std::nullopt;
  Handle type(H5Aget_type(a), H5Tclose);
  Handle space(H5Aget_space(a), H5Sclose);
  if (H5Tget_class(type) != H5T_STRING) return std::nullopt;
  const hssize_t n = H5Sget_simple_extent_npoints(space);
  if (n < 1 || n > 4096) return std::nullopt;
  if (H5Tis_variable_str(type) > 0) {
    if (n != 1) return std::nullopt;
    char* text = nullptr;
    Handle mem(H5Tget_native_type(type, H5T_DIR_DEFAULT), H5Tclose);
    if (H5Aread(a, mem, &text) < 0 || !text) return std::nullopt;
    std::string s(text);
    H5free_memory(text);
    return s;
  }
  const std::size_t size = H5Tget_size(type);
  std::vector<char> buf(size * static_cast<std::size_t>(n) + 1, '\0');
  if (H5Aread(a, type, buf.data()) < 0) return std::nullopt;
  std::string s(buf.data(), size * static_cast<std::size_t>(n));
  s.erase(std::remove(s.begin(), s.end(), '\0'), s.end());
  return s;
}

// A numeric attribute's values as doubles; nullopt when absent or not numeric.
std::optional<std::vector<double>> numeric_attribute(hid_t file, const std::string& object, const char* name) {
  if (H5Aexists_by_name(file, object.c_str(), name, H5P_DEFAULT) <= 0) return std::nullopt;
  Handle a(H5Aopen_by_name(file, object.c_str(), name, H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
  Handle type(H5Aget_type(a), H5Tclose);
  Handle space(H5Aget_space(a), H5Sclose);
  const H5T_class_t c = H5Tget_class(type);
  if (c != H5T_INTEGER && c != H5T_FLOAT) return std::nullopt;
  const hssize_t n = H5Sget_simple_extent_npoints(space);
  if (n < 1 || n > 64) return std::nullopt;
  std::vector<double> values(static_cast<std::size_t>(n));
  if (H5Aread(a, H5T_NATIVE_DOUBLE, values.data()) < 0) return std::nullopt;
  return values;
}

double number_of(const fs::path& path, const std::string& where, const std::optional<std::string>& text) {
  const std::optional<double> v = text ? detail::parse_double(*text) : std::nullopt;
  if (!v || !std::isfinite(*v)) {
    fail_input(path, where + (text ? " = '" + printable(*text, 40) + "' is not a number" : " is missing"));
  }
  return *v;
}

int index_of(const fs::path& path, const std::optional<int>& wanted, int count, const char* what, const char* flag) {
  if (wanted) {
    if (*wanted < 0 || *wanted >= count) {
      fail_input(path, std::string(what) + " " + std::to_string(*wanted) + " does not exist (" + std::to_string(count) +
                           " " + what + (count == 1 ? "" : "s") + ": 0.." + std::to_string(count - 1) + ")");
    }
    return *wanted;
  }
  if (count > 1) {
    fail_input(path, "holds " + std::to_string(count) + " " + what + "s: choose one with " + flag + " (0.." +
                         std::to_string(count - 1) + ")");
  }
  return 0;
}

// ---------------------------------------------------------------------------
// BigDataViewer's XML (the few elements hisnegs needs; not a general XML parser).

// The text between <tag ...> and </tag> of the first such element at or after `from`.
std::optional<std::string> element_text(const std::string& xml, const std::string& tag, std::size_t from = 0,
                                        std::size_t* end = nullptr) {
  std::size_t open = from;
  while ((open = xml.find("<" + tag, open)) != std::string::npos) {
    const char next = open + tag.size() + 1 < xml.size() ? xml[open + tag.size() + 1] : '\0';
    if (next == '>' || next == ' ' || next == '\t' || next == '\n' || next == '\r') break;
    ++open;
  }
  if (open == std::string::npos) return std::nullopt;
  const std::size_t body = xml.find('>', open);
  const std::size_t close = body == std::string::npos ? body : xml.find("</" + tag + ">", body);
  if (close == std::string::npos) return std::nullopt;
  if (end) *end = close + tag.size() + 3;
  return xml.substr(body + 1, close - body - 1);
}

std::string trimmed(std::string s) {
  const auto blank = [](unsigned char c) { return std::isspace(c) != 0; };
  s.erase(s.begin(), std::find_if_not(s.begin(), s.end(), blank));
  s.erase(std::find_if_not(s.rbegin(), s.rend(), blank).base(), s.end());
  return s;
}

std::string read_text(const fs::path& path, std::size_t limit) {
  require_regular_file(path);
  std::ifstream in(path, std::ios::binary);
  std::string text;
  text.resize(limit);
  in.read(text.data(), static_cast<std::streamsize>(limit));
  text.resize(static_cast<std::size_t>(in.gcount()));
  return text;
}

bool is_bdv_xml(const fs::path& path) {
  if (path.extension() != ".xml") return false;
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return false;
  const std::string head = read_text(path, 4096);
  return head.find("<SpimData") != std::string::npos;
}

struct BdvXml {
  fs::path h5;
  std::vector<int> setup_ids;
  std::vector<std::array<double, 3>> voxel_um;  // per setup, x y z
  std::vector<bool> has_voxel;
};

BdvXml parse_bdv_xml(const fs::path& path) {
  const std::string xml = read_text(path, 16u << 20);
  BdvXml out;
  const auto loader = element_text(xml, "ImageLoader");
  const auto h5 = loader ? element_text(*loader, "hdf5") : std::nullopt;
  if (!h5 || trimmed(*h5).empty()) {
    fail_input(path, "BigDataViewer XML without <ImageLoader format=\"bdv.hdf5\"><hdf5>FILE</hdf5>");
  }
  const fs::path named = trimmed(*h5);
  out.h5 = named.is_absolute() ? named : path.parent_path() / named;
  std::size_t at = 0, end = 0;
  while (const auto setup = element_text(xml, "ViewSetup", at, &end)) {
    at = end;
    const auto id = element_text(*setup, "id");
    const std::optional<long long> n = id ? detail::parse_integer(trimmed(*id)) : std::nullopt;
    if (!n || *n < 0 || *n > 99999) fail_input(path, "a <ViewSetup> without a valid <id>");
    out.setup_ids.push_back(static_cast<int>(*n));
    std::array<double, 3> um{1.0, 1.0, 1.0};
    bool has = false;
    if (const auto voxel = element_text(*setup, "voxelSize")) {
      const auto unit = element_text(*voxel, "unit");
      const auto size = element_text(*voxel, "size");
      const std::optional<double> scale = detail::length_unit_um(unit ? trimmed(*unit) : "um");
      std::istringstream in(size ? *size : "");
      std::array<std::string, 3> parts;
      in >> parts[0] >> parts[1] >> parts[2];
      for (int a = 0; a < 3; ++a) {
        const std::optional<double> v = detail::parse_double(parts[a]);
        if (!v || !scale || voxel_size_problem(*v * *scale).size()) {
          fail_input(path, "<voxelSize> of setup " + std::to_string(*n) + ": '" + printable(size ? *size : "", 60) +
                               "' " + printable(unit ? *unit : "", 20) + " is not three voxel sizes");
        }
        um[a] = *v * *scale;
      }
      has = true;
    }
    out.voxel_um.push_back(um);
    out.has_voxel.push_back(has);
  }
  if (out.setup_ids.empty()) fail_input(path, "BigDataViewer XML without a <ViewSetup>");
  return out;
}

// ---------------------------------------------------------------------------
// Dataset checks shared by the layouts.

// Fills type, dims, chunk and filters of `info` from the dataset; refuses what
// hisnegs cannot read.
void describe_dataset(const fs::path& path, hid_t file, Hdf5StackInfo& info) {
  const Handle d = open_dataset(path, file, info.dataset);
  Handle space(H5Dget_space(d), H5Sclose);
  const int rank = H5Sget_simple_extent_ndims(space);
  if (rank < 1 || rank > 8) fail_input(path, "dataset " + printable(info.dataset, 120) + " has no simple extent");
  std::vector<hsize_t> dims(static_cast<std::size_t>(rank));
  H5Sget_simple_extent_dims(space, dims.data(), nullptr);
  info.dims.assign(dims.begin(), dims.end());
  Handle type(H5Dget_type(d), H5Tclose);
  const H5T_class_t c = H5Tget_class(type);
  const std::size_t size = H5Tget_size(type);
  const bool is_signed = c == H5T_INTEGER && H5Tget_sign(type) == H5T_SGN_2;
  std::string type_text = (c == H5T_INTEGER ? (is_signed ? "int" : "uint") : c == H5T_FLOAT ? "float" : "class ") +
                          std::to_string(c == H5T_INTEGER || c == H5T_FLOAT ? size * 8 : static_cast<int>(c));
  if (c == H5T_INTEGER && !is_signed && size == 1) {
    info.type = SampleType::kUint8;
  } else if (c == H5T_INTEGER && !is_signed && size == 2) {
    info.type = SampleType::kUint16;
  } else if (c == H5T_INTEGER && is_signed && size == 2 && info.layout == Hdf5Layout::kBigDataViewer) {
    info.type = SampleType::kUint16;  // BigDataViewer's int16 holds uint16 bits
    info.bdv_signed16 = true;
  } else if (c == H5T_FLOAT && size == 4) {
    info.type = SampleType::kFloat32;
  } else {
    fail_input(path, "dataset " + printable(info.dataset, 120) + " holds " + type_text +
                         " samples; hisnegs reads 8/16-bit unsigned integers and float32");
  }
  Handle dcpl(H5Dget_create_plist(d), H5Pclose);
  check_outside_storage(path, dcpl, info.dataset);
  info.chunk.clear();
  if (H5Pget_layout(dcpl) == H5D_CHUNKED) {
    std::vector<hsize_t> chunk(static_cast<std::size_t>(rank));
    H5Pget_chunk(dcpl, rank, chunk.data());
    info.chunk.assign(chunk.begin(), chunk.end());
    const int filters = H5Pget_nfilters(dcpl);
    for (int i = 0; i < filters; ++i) {
      unsigned flags = 0, config = 0;
      std::size_t n = 0;
      char name[64] = {0};
      const H5Z_filter_t id = H5Pget_filter2(dcpl, static_cast<unsigned>(i), &flags, &n, nullptr, sizeof name, name, &config);
      if (H5Zfilter_avail(id) <= 0) {
        fail_input(path, "dataset " + printable(info.dataset, 120) + " is compressed with filter " + std::to_string(id) +
                             (name[0] ? " (" + printable(name, 40) + ")" : std::string()) +
                             ", which this libhdf5 does not have (it has gzip/deflate, shuffle, fletcher32, "
                             "scaleoffset, nbit" +
                             (H5Zfilter_avail(H5Z_FILTER_SZIP) > 0 ? ", szip" : "") + ")");
      }
      info.filters.emplace_back(id == H5Z_FILTER_DEFLATE ? "gzip" : name[0] ? name : "filter " + std::to_string(id));
    }
    // Chunks that were never written read as the fill value without an error: a
    // partly written (or damaged) file would pass for a stack with empty blocks.
    hsize_t written = 0;
    if (H5Dget_num_chunks(d, space, &written) >= 0) {
      double expected = 1.0;
      for (int a = 0; a < rank; ++a) expected *= std::ceil(static_cast<double>(dims[a]) / static_cast<double>(chunk[a]));
      if (static_cast<double>(written) < expected) {
        fail_input(path, "dataset " + printable(info.dataset, 120) + ": " +
                             std::to_string(static_cast<long long>(expected - static_cast<double>(written))) + " of " +
                             std::to_string(static_cast<long long>(expected)) +
                             " chunks were never written (a missing chunk reads as the fill value, not data)");
      }
    }
  }
}

std::string join_dims(const std::vector<long long>& dims) {
  std::string s;
  for (std::size_t i = 0; i < dims.size(); ++i) s += (i ? "x" : "") + std::to_string(dims[i]);
  return s;
}

// The plain layout: the dataset named, or the only one that can be a stack.
void resolve_plain(const fs::path& path, hid_t file, const Hdf5ReadOptions& options, Hdf5StackInfo& info) {
  info.layout = Hdf5Layout::kPlain;
  if (!options.dataset.empty()) {
    info.dataset = options.dataset.front() == '/' ? options.dataset : "/" + options.dataset;
    if (!link_exists(file, info.dataset)) {
      fail_input(path, "has no dataset " + printable(info.dataset, 120));
    }
    H5O_info_t object;
    if (H5Oget_info_by_name(file, info.dataset.c_str(), &object, H5P_DEFAULT) < 0 || object.type != H5O_TYPE_DATASET) {
      fail_input(path, printable(info.dataset, 120) + " is not a dataset");
    }
  } else {
    struct Found {
      std::vector<std::string> names;
      hid_t file;
    } found{{}, file};
    H5Ovisit(
        file, H5_INDEX_NAME, H5_ITER_INC,
        [](hid_t, const char* name, const H5O_info_t* object, void* data) -> herr_t {
          auto* f = static_cast<Found*>(data);
          if (object->type != H5O_TYPE_DATASET) return 0;
          Handle d(H5Dopen2(f->file, name, H5P_DEFAULT), H5Dclose);
          if (!d.ok()) return 0;
          Handle space(H5Dget_space(d), H5Sclose);
          const int rank = H5Sget_simple_extent_ndims(space);
          if (rank >= 3 && rank <= 5) f->names.push_back(std::string("/") + name);
          return 0;
        },
        &found);
    if (found.names.empty()) fail_input(path, "holds no dataset of rank 3 to 5 (a stack)");
    if (found.names.size() > 1) {
      std::string list;
      for (std::size_t i = 0; i < found.names.size() && i < 6; ++i) list += (i ? ", " : "") + printable(found.names[i], 60);
      fail_input(path, "holds " + std::to_string(found.names.size()) + " datasets that could be the stack (" + list +
                           (found.names.size() > 6 ? ", ..." : "") + "): choose one with --dataset");
    }
    info.dataset = found.names.front();
  }
  describe_dataset(path, file, info);
  const std::size_t rank = info.dims.size();
  if (rank < 3 || rank > 5) {
    fail_input(path, "dataset " + printable(info.dataset, 120) + " is " + join_dims(info.dims) + " (rank " +
                         std::to_string(rank) + "); a stack is Z x Y x X, or C x Z x Y x X / T x C x Z x Y x X");
  }
  if (rank == 5) {
    info.timepoints = static_cast<int>(std::min<long long>(info.dims[0], 1 << 30));
    info.time_index = index_of(path, options.timepoint, info.timepoints, "time point", "--timepoint");
  } else if (options.timepoint && *options.timepoint != 0) {
    fail_input(path, "dataset " + printable(info.dataset, 120) + " has no time axis (--timepoint " +
                         std::to_string(*options.timepoint) + ")");
  }
  if (rank >= 4) {
    info.channels = static_cast<int>(std::min<long long>(info.dims[rank - 4], 1 << 30));
    info.channel_index = index_of(path, options.channel, info.channels, "channel", "--channel");
  } else if (options.channel && *options.channel != 0) {
    fail_input(path, "dataset " + printable(info.dataset, 120) + " has one channel (--channel " +
                         std::to_string(*options.channel) + ")");
  }
  // element_size_um (z, y, x), as Fiji's HDF5 plugin and ilastik write it.
  if (const auto size = numeric_attribute(file, info.dataset, "element_size_um")) {
    if (size->size() != 3) {
      fail_input(path, "dataset " + printable(info.dataset, 120) + ": element_size_um has " +
                           std::to_string(size->size()) + " values, expected z, y, x");
    }
    for (int a = 0; a < 3; ++a) {
      const double um = (*size)[2 - a];
      if (const std::string problem = voxel_size_problem(um); !problem.empty()) {
        fail_input(path, "element_size_um = " + number_text(um) + ": " + problem);
      }
      info.spacing.um[a] = um;
      info.spacing.source[a] = SpacingSource::kHdf5;
    }
  }
}

void resolve_bdv(const fs::path& shown, const fs::path& h5, hid_t file, const BdvXml* xml,
                 const Hdf5ReadOptions& options, Hdf5StackInfo& info) {
  info.layout = Hdf5Layout::kBigDataViewer;
  const std::vector<std::string> members = group_members(file, "/");
  const int setups = static_cast<int>(std::count_if(members.begin(), members.end(), [](const std::string& n) {
    return n.size() == 3 && n[0] == 's' && std::isdigit(static_cast<unsigned char>(n[1])) &&
           std::isdigit(static_cast<unsigned char>(n[2]));
  }));
  info.timepoints = static_cast<int>(std::count_if(members.begin(), members.end(), [](const std::string& n) {
    return n.size() == 6 && n[0] == 't' && std::all_of(n.begin() + 1, n.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); });
  }));
  if (info.timepoints == 0 || setups == 0) fail_input(shown, "BigDataViewer file without t00000/s00 groups");
  info.channels = setups;
  const int setup = index_of(shown, options.channel, setups, "setup", "--channel");
  const int t = index_of(shown, options.timepoint, info.timepoints, "time point", "--timepoint");
  char name[64];
  std::snprintf(name, sizeof name, "/t%05d/s%02d/0/cells", t, setup);
  info.dataset = name;
  if (!link_exists(file, info.dataset)) fail_input(h5, "has no dataset " + info.dataset);
  describe_dataset(h5, file, info);
  if (info.dims.size() != 3) {
    fail_input(h5, "dataset " + info.dataset + " is " + join_dims(info.dims) + ", not Z x Y x X");
  }
  if (xml) {
    for (std::size_t i = 0; i < xml->setup_ids.size(); ++i) {
      if (xml->setup_ids[i] != setup || !xml->has_voxel[i]) continue;
      for (int a = 0; a < 3; ++a) {
        info.spacing.um[a] = xml->voxel_um[i][a];
        info.spacing.source[a] = SpacingSource::kHdf5;
      }
    }
  }
}

void resolve_imaris(const fs::path& path, hid_t file, const Hdf5ReadOptions& options, Hdf5StackInfo& info) {
  info.layout = Hdf5Layout::kImaris;
  const std::string level = "/DataSet/ResolutionLevel 0";
  int timepoints = 0, channels = 0;
  for (const std::string& n : group_members(file, level)) timepoints += n.rfind("TimePoint ", 0) == 0 ? 1 : 0;
  for (const std::string& n : group_members(file, level + "/TimePoint 0")) channels += n.rfind("Channel ", 0) == 0 ? 1 : 0;
  if (timepoints == 0 || channels == 0) fail_input(path, "Imaris file without TimePoint 0/Channel 0 at resolution level 0");
  info.timepoints = timepoints;
  info.channels = channels;
  const int t = index_of(path, options.timepoint, timepoints, "time point", "--timepoint");
  const int c = index_of(path, options.channel, channels, "channel", "--channel");
  const std::string group = level + "/TimePoint " + std::to_string(t) + "/Channel " + std::to_string(c);
  info.dataset = group + "/Data";
  if (!link_exists(file, info.dataset)) fail_input(path, "has no dataset " + info.dataset);
  describe_dataset(path, file, info);
  if (info.dims.size() != 3) fail_input(path, "dataset " + info.dataset + " is " + join_dims(info.dims) + ", not Z x Y x X");
  // The image's size: the channel's ImageSize{X,Y,Z} (the dataset is padded to whole
  // chunks), else DataSetInfo/Image X, Y, Z.
  const std::string image = "/DataSetInfo/Image";
  std::array<long long, 3> size{};
  const char* channel_keys[3] = {"ImageSizeX", "ImageSizeY", "ImageSizeZ"};
  const char* image_keys[3] = {"X", "Y", "Z"};
  for (int a = 0; a < 3; ++a) {
    std::optional<std::string> text = string_attribute(file, group, channel_keys[a]);
    std::string where = info.dataset.substr(0, info.dataset.size() - 5) + " " + channel_keys[a];
    if (!text) {
      text = string_attribute(file, image, image_keys[a]);
      where = image + " " + image_keys[a];
    }
    const double v = number_of(path, where, text);
    const long long stored = info.dims[2 - a];
    if (v < 1 || v > static_cast<double>(stored) || v != std::floor(v)) {
      fail_input(path, where + " = " + number_text(v) + " does not fit the dataset's " + std::to_string(stored) +
                           " voxels along " + "xyz"[a]);
    }
    size[a] = static_cast<long long>(v);
  }
  info.nx = static_cast<int>(size[0]);
  info.ny = static_cast<int>(size[1]);
  info.nz = static_cast<int>(size[2]);
  // Spacing: (ExtMax - ExtMin) / size per axis, in DataSetInfo/Image's Unit (µm by
  // default); --spacing stands in for extents a file lacks.
  if (options.spacing_um) return;
  const std::optional<std::string> unit_text = string_attribute(file, image, "Unit");
  const std::optional<double> unit = detail::length_unit_um(unit_text ? trimmed(*unit_text) : "um");
  if (!unit) fail_input(path, image + " Unit = '" + printable(*unit_text, 20) + "' is not a length unit");
  for (int a = 0; a < 3; ++a) {
    const std::string lo_key = "ExtMin" + std::to_string(a), hi_key = "ExtMax" + std::to_string(a);
    const double lo = number_of(path, image + " " + lo_key, string_attribute(file, image, lo_key.c_str()));
    const double hi = number_of(path, image + " " + hi_key, string_attribute(file, image, hi_key.c_str()));
    const double um = (hi - lo) / static_cast<double>(size[a]) * *unit;
    if (const std::string problem = voxel_size_problem(um); !problem.empty()) {
      fail_input(path, image + " " + lo_key + "/" + hi_key + " give a voxel size of " + number_text(um) + " um along " +
                           "xyz"[a] + ": " + problem);
    }
    info.spacing.um[a] = um;
    info.spacing.source[a] = SpacingSource::kHdf5;
  }
}

// Integers are read as stored and widened here: libhdf5's own integer-to-float
// conversion is several times slower than the decode.
template <class Stored>
herr_t read_widened(hid_t dataset, hid_t memtype, hid_t memory, hid_t space, hsize_t voxels, float* out) {
  std::vector<Stored> stored(voxels);
  const herr_t status = H5Dread(dataset, memtype, memory, space, H5P_DEFAULT, stored.data());
  std::copy(stored.begin(), stored.end(), out);
  return status;
}

void apply_user_spacing(const Hdf5ReadOptions& options, Hdf5StackInfo& info) {
  if (!options.spacing_um) return;
  for (int a = 0; a < 3; ++a) {
    info.spacing.um[a] = (*options.spacing_um)[a];
    info.spacing.source[a] = SpacingSource::kUser;
  }
}

}  // namespace

std::string Hdf5StackInfo::describe() const {
  std::string s = layout == Hdf5Layout::kImaris          ? "Imaris (.ims)"
                  : layout == Hdf5Layout::kBigDataViewer ? "BigDataViewer HDF5"
                                                         : "HDF5";
  s += ", " + dataset.substr(dataset.front() == '/' ? 1 : 0) + " " + join_dims(dims) + ", " +
       std::string(to_string(type)) + (bdv_signed16 ? " (stored as int16)" : "");
  s += chunk.empty() ? ", contiguous" : ", chunks " + join_dims(chunk);
  for (const std::string& f : filters) s += ", " + f;
  if (channels > 1) s += ", " + std::to_string(channels) + " channels";
  if (timepoints > 1) s += ", " + std::to_string(timepoints) + " time points";
  return s;
}

bool is_hdf5_stack(const fs::path& path) {
  // Not opened unless it is a regular file: opening a FIFO for its signature blocked
  // every command that reads a stack (the TIFF reader then refuses it by name).
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return false;
  if (is_bdv_xml(path)) return true;
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  static constexpr char kSignature[8] = {'\x89', 'H', 'D', 'F', '\r', '\n', '\x1a', '\n'};
  // The superblock may follow a user block of 512, 1024, 2048, ... bytes.
  for (std::uint64_t at = 0; at <= (1u << 20); at = at ? at * 2 : 512) {
    char head[8];
    in.seekg(static_cast<std::streamoff>(at));
    if (!in.read(head, 8)) return false;
    if (std::memcmp(head, kSignature, 8) == 0) return true;
  }
  return false;
}

std::vector<fs::path> hdf5_stack_files(const fs::path& path) {
  if (is_bdv_xml(path)) return {path, parse_bdv_xml(path).h5};
  fs::path beside = path;
  beside.replace_extension(".xml");
  if (beside != path && is_bdv_xml(beside)) return {path, beside};
  return {path};
}

Hdf5StackInfo inspect_hdf5_stack(const fs::path& path, const Hdf5ReadOptions& options) {
  std::lock_guard<std::mutex> lock(hdf5_mutex());
  silence_hdf5();
  Hdf5StackInfo info;
  std::optional<BdvXml> xml;
  fs::path h5 = path;
  if (is_bdv_xml(path)) {
    xml = parse_bdv_xml(path);
    h5 = xml->h5;
    std::error_code ec;
    if (!fs::exists(h5, ec)) fail_input(path, "names " + printable(h5.string(), 200) + ", which does not exist");
    if (!fs::is_regular_file(h5, ec)) {
      fail_input(path, "names " + printable(h5.string(), 200) +
                           ", which is not a regular file (a folder, device, FIFO or socket)");
    }
  } else {
    require_regular_file(path);
  }
  info.file = h5;
  const Handle file = open_file(h5);
  if (xml || (link_exists(file, "/t00000") && link_exists(file, "/s00/resolutions"))) {
    std::optional<BdvXml> sibling;
    if (!xml) {
      fs::path beside = h5;
      beside.replace_extension(".xml");
      if (is_bdv_xml(beside)) sibling = parse_bdv_xml(beside);
    }
    resolve_bdv(path, h5, file, xml ? &*xml : sibling ? &*sibling : nullptr, options, info);
  } else if (link_exists(file, "/DataSet/ResolutionLevel 0")) {
    resolve_imaris(path, file, options, info);
  } else {
    resolve_plain(path, file, options, info);
  }
  if (info.layout != Hdf5Layout::kImaris) {
    const std::size_t r = info.dims.size();
    info.nz = static_cast<int>(info.dims[r - 3]);
    info.ny = static_cast<int>(info.dims[r - 2]);
    info.nx = static_cast<int>(info.dims[r - 1]);
    for (std::size_t a = r - 3; a < r; ++a) {
      if (info.dims[a] < 1) {
        fail_input(path, "dataset " + printable(info.dataset, 120) + " is " + join_dims(info.dims) + ": an empty axis");
      }
      if (info.dims[a] > (1 << 30)) {
        fail_input(path, "dataset " + printable(info.dataset, 120) + " is " + join_dims(info.dims) + ": too large an axis");
      }
    }
    if (info.nz == 1) {  // as a one-page TIFF is
      fail_input(path, "dataset " + printable(info.dataset, 120) + " is " + join_dims(info.dims) +
                           ": a single 2D image (1 plane); expected a 3D stack");
    }
  }
  apply_user_spacing(options, info);
  return info;
}

void read_hdf5_region(const Hdf5StackInfo& info, const std::array<int, 3>& lo, const std::array<int, 3>& hi,
                      float* out) {
  const std::array<int, 3> n{info.nx, info.ny, info.nz};
  for (int a = 0; a < 3; ++a) {
    if (lo[a] < 0 || hi[a] > n[a] || lo[a] >= hi[a]) {
      throw std::invalid_argument("read_hdf5_region: the box is empty or outside the stack");
    }
  }
  std::lock_guard<std::mutex> lock(hdf5_mutex());
  silence_hdf5();
  const Handle file = open_file(info.file);
  const Handle d = open_dataset(info.file, file, info.dataset);
  const std::size_t rank = info.dims.size();
  std::vector<hsize_t> start(rank, 0), count(rank, 1);
  if (rank >= 4) start[rank - 4] = static_cast<hsize_t>(info.channel_index);
  if (rank == 5) start[0] = static_cast<hsize_t>(info.time_index);
  for (int a = 0; a < 3; ++a) {
    start[rank - 1 - a] = static_cast<hsize_t>(lo[a]);
    count[rank - 1 - a] = static_cast<hsize_t>(hi[a] - lo[a]);
  }
  Handle space(H5Dget_space(d), H5Sclose);
  H5Sselect_hyperslab(space, H5S_SELECT_SET, start.data(), nullptr, count.data(), nullptr);
  const hsize_t voxels = count[rank - 1] * count[rank - 2] * count[rank - 3];
  // The memory space has the selection's own shape: a flat one sends libhdf5 down
  // its element-by-element path (5x slower on a whole gzip stack).
  Handle memory(H5Screate_simple(static_cast<int>(rank), count.data(), nullptr), H5Sclose);
  herr_t status = 0;
  if (info.bdv_signed16) {
    // Converting int16 to H5T_NATIVE_UINT16 would clip the negatives to 0: read the
    // int16 bits into uint16 words, which then hold the uint16 BigDataViewer stored.
    status = read_widened<std::uint16_t>(d, H5T_NATIVE_INT16, memory, space, voxels, out);
  } else if (info.type == SampleType::kUint8) {
    status = read_widened<std::uint8_t>(d, H5T_NATIVE_UINT8, memory, space, voxels, out);
  } else if (info.type == SampleType::kUint16) {
    status = read_widened<std::uint16_t>(d, H5T_NATIVE_UINT16, memory, space, voxels, out);
  } else {
    status = H5Dread(d, H5T_NATIVE_FLOAT, memory, space, H5P_DEFAULT, out);
  }
  if (status < 0) {
    fail_input(info.file, "dataset " + printable(info.dataset, 120) + ": cannot read voxels [" + std::to_string(lo[0]) +
                              ".." + std::to_string(hi[0]) + ") x [" + std::to_string(lo[1]) + ".." +
                              std::to_string(hi[1]) + ") x [" + std::to_string(lo[2]) + ".." + std::to_string(hi[2]) +
                              ")" + hdf5_error());
  }
  if (info.type == SampleType::kFloat32) {
    for (hsize_t i = 0; i < voxels; ++i) {
      if (!std::isfinite(out[i])) fail_input(info.file, "dataset " + printable(info.dataset, 120) + " holds NaN/Inf");
    }
  }
}

Volume read_hdf5_stack(const fs::path& path, const Hdf5ReadOptions& options) {
  const Hdf5StackInfo info = inspect_hdf5_stack(path, options);
  check_allocation(path, 4.0 * info.nx * info.ny * static_cast<double>(info.nz), "the stack as float32");
  Volume v;
  v.nx = info.nx;
  v.ny = info.ny;
  v.nz = info.nz;
  v.stored_as = info.type;
  v.spacing = info.spacing;
  v.source = path.string();
  v.voxels.resize(v.size());
  read_hdf5_region(info, {0, 0, 0}, {info.nx, info.ny, info.nz}, v.voxels.data());
  return v;
}

void write_hdf5_stack(const fs::path& path, const Volume& volume, const Hdf5WriteOptions& options) {
  if (options.gzip_level < 0 || options.gzip_level > 9) {
    throw InputError("hdf5.gzip_level = " + std::to_string(options.gzip_level) + ": must be in [0, 9]");
  }
  const hid_t memtype = options.type == SampleType::kUint8    ? H5T_NATIVE_UINT8
                        : options.type == SampleType::kUint16 ? H5T_NATIVE_UINT16
                                                              : H5T_NATIVE_FLOAT;
  const hid_t filetype = options.type == SampleType::kUint8    ? H5T_STD_U8LE
                         : options.type == SampleType::kUint16 ? H5T_STD_U16LE
                                                               : H5T_IEEE_F32LE;
  const double top = options.type == SampleType::kUint8 ? 255.0 : 65535.0;
  for (std::size_t i = 0; i < volume.voxels.size() && options.type != SampleType::kFloat32; ++i) {
    const double v = volume.voxels[i];
    if (!(v >= 0.0 && v <= top && v == std::floor(v))) {
      fail_input(path, "voxel " + std::to_string(i) + " = " + number_text(v) + " does not fit " +
                           std::string(to_string(options.type)));
    }
  }
  AtomicFile target(path);
  {
    std::lock_guard<std::mutex> lock(hdf5_mutex());
    silence_hdf5();
    Handle file(H5Fcreate(target.temp_path().c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT), H5Fclose);
    if (!file.ok()) throw WriteError(path.string() + ": cannot create the HDF5 file" + hdf5_error());
    const std::array<hsize_t, 3> dims{static_cast<hsize_t>(volume.nz), static_cast<hsize_t>(volume.ny),
                                      static_cast<hsize_t>(volume.nx)};
    Handle space(H5Screate_simple(3, dims.data(), nullptr), H5Sclose);
    Handle dcpl(H5Pcreate(H5P_DATASET_CREATE), H5Pclose);
    std::array<hsize_t, 3> chunk{};
    for (int a = 0; a < 3; ++a) chunk[a] = std::clamp<hsize_t>(static_cast<hsize_t>(options.chunk_zyx[a]), 1, dims[a]);
    H5Pset_chunk(dcpl, 3, chunk.data());
    if (options.gzip_level > 0) H5Pset_deflate(dcpl, static_cast<unsigned>(options.gzip_level));
    Handle lcpl(H5Pcreate(H5P_LINK_CREATE), H5Pclose);
    H5Pset_create_intermediate_group(lcpl, 1);
    Handle d(H5Dcreate2(file, options.dataset.c_str(), filetype, space, lcpl, dcpl, H5P_DEFAULT), H5Dclose);
    if (!d.ok()) throw WriteError(path.string() + ": cannot create dataset " + options.dataset + hdf5_error());
    herr_t status = 0;
    if (options.type == SampleType::kFloat32) {
      status = H5Dwrite(d, memtype, H5S_ALL, H5S_ALL, H5P_DEFAULT, volume.voxels.data());
    } else {
      // float -> integer conversion by libhdf5 rounds toward zero; the values are exact integers.
      status = H5Dwrite(d, H5T_NATIVE_FLOAT, H5S_ALL, H5S_ALL, H5P_DEFAULT, volume.voxels.data());
    }
    const std::array<double, 3> element{volume.spacing.um[2], volume.spacing.um[1], volume.spacing.um[0]};
    const hsize_t three = 3;
    Handle aspace(H5Screate_simple(1, &three, nullptr), H5Sclose);
    Handle attr(H5Acreate2(d, "element_size_um", H5T_IEEE_F64LE, aspace, H5P_DEFAULT, H5P_DEFAULT), H5Aclose);
    if (status < 0 || !attr.ok() || H5Awrite(attr, H5T_NATIVE_DOUBLE, element.data()) < 0 || H5Fflush(file, H5F_SCOPE_GLOBAL) < 0) {
      throw WriteError(path.string() + ": cannot write the HDF5 data" + hdf5_error());
    }
  }
  target.commit();
}

}  // namespace hisnegs::io
