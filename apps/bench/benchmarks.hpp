// Google Benchmark suites run by `hisnegs bench SUITE`. Each registers its
// benchmarks; cmd_bench runs them. Timings are wall clock (UseRealTime) since
// the code under test is TBB-parallel.
#pragma once

#include <filesystem>

namespace hisnegs::apps::bench {

// Loading, normalizing and sparsifying `volume` (a TIFF stack).
void register_io_benchmarks(const std::filesystem::path& volume);

}  // namespace hisnegs::apps::bench
