// SPDX-License-Identifier: Apache-2.0
// load_checkpoint (declared in gmf/core/checkpoint.hpp): the one reader of every
// checkpoint format, the PLY (gmf/core/checkpoint.hpp), the compact .hgs
// (gmf/core/compact_checkpoint.hpp) and the hierarchy .hgw's model
// (gmf/core/hierarchy_file.hpp), told apart by content. Its own file so that the
// compact format builds on the PLY one and not the other way round.
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "gmf/core/checkpoint.hpp"
#include "gmf/core/compact_checkpoint.hpp"
#include "gmf/core/hierarchy_file.hpp"
#include "io/error.hpp"

namespace hisnegs::gmf {
namespace fs = std::filesystem;

Checkpoint load_checkpoint(const fs::path& path) {
  // By content, not by name: a compact file keeps working whatever it is called.
  // A file that is a cut-short compact magic goes to the compact reader too, which
  // says "truncated" rather than PLY's "not a PLY file".
  // Only a regular file, opened without blocking (a FIFO would hang the reader).
  char head[kCompactMagic.size()] = {};
  std::size_t got = 0;
  {
    const int fd = io::open_regular_file(path);
    ssize_t n = 0;
    while (got < sizeof head && (n = ::read(fd, head + got, sizeof head - got)) != 0) {
      if (n < 0 && errno == EINTR) continue;
      if (n < 0) break;
      got += static_cast<std::size_t>(n);
    }
    ::close(fd);
  }
  if (got == kHierarchyMagic.size() && std::memcmp(head, kHierarchyMagic.data(), got) == 0) {
    return load_hierarchy_model(path);
  }
  if (got > 0 && std::memcmp(head, kCompactMagic.data(), got) == 0) return load_compact_checkpoint(path);
  return checkpoint_from_ply(io::read_ply(path), path);
}

}  // namespace hisnegs::gmf
