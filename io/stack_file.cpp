// SPDX-License-Identifier: Apache-2.0
// read_stack / inspect_stack: the TIFF or HDF5 reader, by the file's signature.
#include "io/stack_file.hpp"

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

}  // namespace hisnegs::io
