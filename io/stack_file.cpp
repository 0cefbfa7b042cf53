// SPDX-License-Identifier: Apache-2.0
// read_stack / inspect_stack: the TIFF or HDF5 reader, by the file's signature.
#include "io/stack_file.hpp"

#include <sys/stat.h>

#include <cerrno>
#include <system_error>

#include "io/atomic_file.hpp"
#include "io/error.hpp"

namespace hisnegs::io {
namespace {

void refuse_hdf5_options(const std::filesystem::path& path, const StackReadOptions& options) {
  if (!options.dataset.empty()) fail_input(path, "--dataset is for HDF5 files; this is a TIFF stack");
  if (options.timepoint) fail_input(path, "--timepoint is for HDF5 files; this is a TIFF stack");
}

}  // namespace

Hdf5ReadOptions StackReadOptions::hdf5() const {
  Hdf5ReadOptions h;
  h.dataset = dataset;
  h.channel = tiff.channel;
  h.timepoint = timepoint;
  h.spacing_um = tiff.spacing_um;
  return h;
}

StackHeader inspect_stack(const std::filesystem::path& path, const StackReadOptions& options) {
  StackHeader h;
  if (is_hdf5_stack(path)) {
    const Hdf5StackInfo info = inspect_hdf5_stack(path, options.hdf5());
    h.nx = info.nx, h.ny = info.ny, h.nz = info.nz;
    h.type = info.type;
    h.spacing = info.spacing;
    h.channels = info.channels;
    h.format = info.describe();
    return h;
  }
  refuse_hdf5_options(path, options);
  const TiffStackInfo info = inspect_tiff_stack(path, options.tiff);
  h.nx = info.nx, h.ny = info.ny, h.nz = info.nz;
  h.type = info.type;
  h.spacing = info.spacing;
  h.channels = info.channels;
  h.format = std::string("TIFF") + (info.bigtiff ? " (BigTIFF)" : "") + ", " + std::to_string(info.pages) + " pages, " +
             std::string(to_string(info.type)) + ", " + info.compression + ", " + (info.tiled ? "tiled" : "striped") +
             (info.channels > 1 ? ", " + std::to_string(info.channels) + " channels" : "");
  return h;
}

Volume read_stack(const std::filesystem::path& path, const StackReadOptions& options) {
  if (is_hdf5_stack(path)) return read_hdf5_stack(path, options.hdf5());
  refuse_hdf5_options(path, options);
  return read_tiff_stack(path, options.tiff);
}

std::vector<std::filesystem::path> stack_files(const std::filesystem::path& path) {
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

}  // namespace

std::string StackIdentity::content() const {
  std::string text;
  std::error_code ec;
  for (std::size_t i = 0; i < files.size(); ++i) {
    if (i > 0) text += "|";
    text += i == 0 || std::filesystem::exists(files[i], ec) ? stat_identity(files[i]) : std::string("missing");
  }
  return text;
}

bool StackIdentity::holds(const std::filesystem::path& path) const {
  for (const std::filesystem::path& file : files) {
    if (same_file(file, path)) return true;
  }
  return false;
}

StackIdentity stack_identity(const std::filesystem::path& path) { return {path, stack_files(path)}; }

}  // namespace hisnegs::io
