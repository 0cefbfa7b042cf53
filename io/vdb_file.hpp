// SPDX-License-Identifier: Apache-2.0
// OpenVDB for the .cpp files of any layer that builds its own grids (gmf's
// `export vdb`): one-time initialization, the CONVENTIONS index->world map as an
// OpenVDB transform, and the atomic .vdb writer. Heavy include: include it only
// from .cpp files, never from another header.
#pragma once

#include <openvdb/openvdb.h>
#include <tbb/task_arena.h>

#include <Eigen/Core>
#include <filesystem>

#include "io/vdb_validate.hpp"

namespace hisnegs::io {

// openvdb::initialize() exactly once per process (thread-safe).
void ensure_openvdb_initialized();

// world = origin_world + voxel_size_world ⊙ index as an OpenVDB linear transform.
// Throws InputError("voxel size V is too small for an OpenVDB transform; ...") when
// OpenVDB refuses the map (voxels of ~1e-5 world units and below).
openvdb::math::Transform::Ptr make_vdb_transform(const Eigen::Vector3d& voxel_size_world,
                                                 const Eigen::Vector3d& origin_world);

// Walks the file as OpenVDB would read it (io/vdb_validate.hpp) and throws
// io::InputError naming it for any length, count or chunk size the file cannot hold.
// Call it before handing the file to openvdb::io::File, read the values only of
// grids it checked (values_checked) and keep a VdbReadGuard alive for the read.
VdbFileCheck check_vdb_structure(const std::filesystem::path& path);

// While alive, caps this process's address space at what it uses now plus
// min(allocation_limit_bytes(), max(1 GiB, 64 × the file's size)): a damaged .vdb
// whose header claims huge strings or buffers makes OpenVDB's allocation fail
// (std::bad_alloc, reported by the readers as a damaged file) instead of taking
// gigabytes. Restores the previous limit on destruction. No-op under
// AddressSanitizer (its shadow memory needs the address space).
// Run OpenVDB's reads through run(): a read that fails unwinds through Tree::clear,
// whose tbb::parallel_for would start worker threads (stacks, arenas) under the cap
// and std::terminate ("pthread_create has failed") from a destructor when none
// fits. run() executes in a one-thread task_arena made before the cap is set, so
// OpenVDB's parallel loops run on the calling thread and start no thread.
class VdbReadGuard {
 public:
  explicit VdbReadGuard(const std::filesystem::path& path);
  ~VdbReadGuard();
  VdbReadGuard(const VdbReadGuard&) = delete;
  VdbReadGuard& operator=(const VdbReadGuard&) = delete;
  [[nodiscard]] double cap_bytes() const { return cap_; }
  // f() on this thread alone (exceptions pass through).
  template <class F>
  void run(F&& f) {
    arena_.execute(std::forward<F>(f));
  }

 private:
  tbb::task_arena arena_{1};
  bool active_ = false;
  unsigned long long previous_soft_ = 0;
  double cap_ = 0;
};

// Writes `grids` to a .vdb file (Blosc) atomically; an OpenVDB failure becomes a
// std::runtime_error naming `path`, and leaves no file.
void write_vdb_file(const std::filesystem::path& path, const openvdb::GridPtrVec& grids);

}  // namespace hisnegs::io
