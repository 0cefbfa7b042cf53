// SPDX-License-Identifier: Apache-2.0
// read_stack / inspect_stack: the TIFF or HDF5 reader, by the file's signature.
#include "io/stack_file.hpp"

#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <system_error>

#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/hash.hpp"
#include "io/memory_limit.hpp"

namespace hisnegs::io {
namespace {

void refuse_hdf5_options(const std::filesystem::path& path, const StackReadOptions& options) {
  if (!options.dataset.empty()) fail_input(path, "--dataset is for HDF5 files; this is a TIFF stack");
  if (options.timepoint) fail_input(path, "--timepoint is for HDF5 and OME-Zarr stacks; this is a TIFF stack");
}

// The fields every reader's inspected header has in common.
template <class Info>
StackHeader common_header(const Info& info) {
  StackHeader h;
  h.nx = info.nx, h.ny = info.ny, h.nz = info.nz;
  h.type = info.type;
  h.spacing = info.spacing;
  h.channels = info.channels;
  return h;
}

}  // namespace

void refuse_level(const std::filesystem::path& path, const StackReadOptions& options) {
  if (options.level != 0) fail_input(path, "--level is for OME-Zarr stacks (multiscale); this file has one level");
}

StackHeader header_of(const Hdf5StackInfo& info) {
  StackHeader h = common_header(info);
  h.format = info.describe();
  return h;
}

StackHeader header_of(const ZarrStackInfo& info) {
  StackHeader h = common_header(info);
  h.format = info.describe();
  return h;
}

ZarrStackInfo inspect_zarr_for(const std::filesystem::path& path, const StackReadOptions& options) {
  if (!options.dataset.empty()) fail_input(path, "--dataset is for HDF5 files; name the Zarr array folder instead");
  return inspect_zarr_stack(path, options.zarr());
}

Hdf5ReadOptions StackReadOptions::hdf5() const {
  Hdf5ReadOptions h;
  h.dataset = dataset;
  h.channel = tiff.channel;
  h.timepoint = timepoint;
  h.spacing_um = tiff.spacing_um;
  return h;
}

ZarrReadOptions StackReadOptions::zarr() const {
  ZarrReadOptions z;
  z.level = level;
  z.channel = tiff.channel;
  z.timepoint = timepoint;
  z.spacing_um = tiff.spacing_um;
  return z;
}

void require_stack_path(const std::filesystem::path& path) {
  if (!is_zarr_stack(path)) require_regular_file(path);
}

StackHeader inspect_stack(const std::filesystem::path& path, const StackReadOptions& options) {
  if (is_zarr_stack(path)) return header_of(inspect_zarr_for(path, options));
  refuse_level(path, options);
  if (is_hdf5_stack(path)) return header_of(inspect_hdf5_stack(path, options.hdf5()));
  refuse_hdf5_options(path, options);
  const TiffStackInfo info = inspect_tiff_stack(path, options.tiff);
  StackHeader h = common_header(info);
  h.format = std::string("TIFF") + (info.bigtiff ? " (BigTIFF)" : "") + ", " + std::to_string(info.pages) + " pages, " +
             std::string(to_string(info.type)) + ", " + info.compression + ", " + (info.tiled ? "tiled" : "striped") +
             (info.channels > 1 ? ", " + std::to_string(info.channels) + " channels" : "");
  return h;
}

Volume read_stack(const std::filesystem::path& path, const StackReadOptions& options) {
  if (is_zarr_stack(path)) {
    const ZarrStackInfo info = inspect_zarr_for(path, options);
    check_allocation(path, 4.0 * info.nx * info.ny * static_cast<double>(info.nz), "the stack as float32");
    Volume v;
    v.nx = info.nx, v.ny = info.ny, v.nz = info.nz;
    v.stored_as = info.type;
    v.spacing = info.spacing;
    v.source = path.string();
    v.voxels.resize(static_cast<std::size_t>(v.nx) * static_cast<std::size_t>(v.ny) * static_cast<std::size_t>(v.nz));
    read_zarr_region(info, {0, 0, 0}, {v.nx, v.ny, v.nz}, v.voxels.data());
    return v;
  }
  refuse_level(path, options);
  if (is_hdf5_stack(path)) return read_hdf5_stack(path, options.hdf5());
  refuse_hdf5_options(path, options);
  return read_tiff_stack(path, options.tiff);
}

std::vector<std::filesystem::path> stack_files(const std::filesystem::path& path) {
  if (is_zarr_stack(path)) return zarr_stack_files(path);
  try {
    if (is_hdf5_stack(path)) return hdf5_stack_files(path);
  } catch (const std::exception&) {  // a malformed .xml: its reader reports it
  }
  return {path};
}

namespace {

std::string stat_identity(const std::filesystem::path& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    throw std::filesystem::filesystem_error("cannot stat", path, std::error_code(errno, std::generic_category()));
  }
  const long long mtime_ns = static_cast<long long>(st.st_mtim.tv_sec) * 1000000000LL + st.st_mtim.tv_nsec;
  return std::to_string(st.st_size) + "|" + std::to_string(mtime_ns) + "|" + std::to_string(st.st_dev) + ":" +
         std::to_string(st.st_ino);
}

// A folder (an OME-Zarr store): every file under it, by count, total size, newest
// modification time and a hash of their names, sizes and times (a chunk rewritten
// in place changes it; so does one added or removed).
std::string folder_identity(const std::filesystem::path& folder) {
  long long count = 0, bytes = 0, newest = 0;
  std::uint64_t hash = fnv1a64("");
  std::vector<std::string> rows;
  for (const auto& entry : std::filesystem::recursive_directory_iterator(folder)) {
    struct stat st {};
    if (::lstat(entry.path().c_str(), &st) != 0 || !S_ISREG(st.st_mode)) continue;
    const long long mtime_ns = static_cast<long long>(st.st_mtim.tv_sec) * 1000000000LL + st.st_mtim.tv_nsec;
    ++count;
    bytes += st.st_size;
    newest = std::max(newest, mtime_ns);
    rows.push_back(entry.path().lexically_relative(folder).string() + ":" + std::to_string(st.st_size) + ":" +
                   std::to_string(mtime_ns));
  }
  std::sort(rows.begin(), rows.end());
  for (const std::string& r : rows) hash = fnv1a64(r.data(), r.size() + 1, hash);  // the NUL separates rows
  return "folder " + std::to_string(count) + " files " + std::to_string(bytes) + " bytes newest " +
         std::to_string(newest) + " " + std::to_string(hash) + "|" + stat_identity(folder);
}

}  // namespace

std::string StackIdentity::content() const {
  std::string text;
  std::error_code ec;
  for (std::size_t i = 0; i < files.size(); ++i) {
    if (i > 0) text += "|";
    if (std::filesystem::is_directory(files[i], ec)) {
      text += folder_identity(files[i]);
    } else {
      text += i == 0 || std::filesystem::exists(files[i], ec) ? stat_identity(files[i]) : std::string("missing");
    }
  }
  return text;
}

bool StackIdentity::holds(const std::filesystem::path& path) const {
  std::error_code ec;
  for (const std::filesystem::path& file : files) {
    if (same_file(file, path)) return true;
    if (is_zarr_stack(file)) {  // anything inside a folder stack is part of it
      const std::filesystem::path folder = std::filesystem::weakly_canonical(file, ec);
      const std::filesystem::path inner = std::filesystem::weakly_canonical(path, ec);
      const auto [f, i] = std::mismatch(folder.begin(), folder.end(), inner.begin(), inner.end());
      if (!ec && f == folder.end()) return true;
    }
  }
  return false;
}

StackIdentity stack_identity(const std::filesystem::path& path) { return {path, stack_files(path)}; }

}  // namespace hisnegs::io
