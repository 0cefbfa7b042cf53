// SPDX-License-Identifier: Apache-2.0
// Job: this process alone, or the ranks of an MPI launch (MPI's C API).
#include "apps/pipeline/distributed.hpp"

#include <algorithm>
#include <charconv>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>

#include "io/error.hpp"

#if HISNEGS_HAVE_MPI
#include <mpi.h>
#endif

namespace hisnegs::apps {

namespace {

class SingleProcess final : public Job {
 public:
  [[nodiscard]] int rank() const override { return 0; }
  [[nodiscard]] int size() const override { return 1; }
  void barrier() const override {}
  void max_to_root(std::span<float>) const override {}
  void merge_soft_to_root(std::span<splat::SoftPixel>) const override {}
  void sum_all(std::span<float>) const override {}
  void sum_all(std::span<double>) const override {}
  void max_all(std::span<double>) const override {}
  void broadcast(std::span<double>) const override {}
  void broadcast(std::vector<unsigned char>&, int) const override {}
  [[nodiscard]] std::vector<std::vector<unsigned char>> exchange(
      const std::vector<std::vector<unsigned char>>&) const override {
    return std::vector<std::vector<unsigned char>>(1);
  }
  [[noreturn]] void abort(int code) const override { std::exit(code); }
};

#if HISNEGS_HAVE_MPI
static_assert(sizeof(splat::SoftPixel) == 3 * sizeof(float), "SoftPixel travels as 3 MPI_FLOATs");

class MpiWorld final : public Job {
 public:
  MpiWorld() {
    int provided = 0;
    // Only the thread that called job() talks to MPI; TBB's threads never do.
    if (MPI_Init_thread(nullptr, nullptr, MPI_THREAD_FUNNELED, &provided) != MPI_SUCCESS) {
      throw io::InputError("MPI could not start (MPI_Init_thread failed)");
    }
    MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
    MPI_Comm_size(MPI_COMM_WORLD, &size_);
    std::atexit([] {
      int finalized = 0;
      MPI_Finalized(&finalized);
      if (!finalized) MPI_Finalize();
    });
  }
  [[nodiscard]] int rank() const override { return rank_; }
  [[nodiscard]] int size() const override { return size_; }
  void barrier() const override { MPI_Barrier(MPI_COMM_WORLD); }
  void max_to_root(std::span<float> values) const override {
    to_root(values.data(), values.size(), MPI_FLOAT, MPI_MAX);
  }
  void merge_soft_to_root(std::span<splat::SoftPixel> pixels) const override {
    to_root(pixels.data(), pixels.size(), soft_pixel_type(), merge_op());
  }
  void sum_all(std::span<float> values) const override {
    sum_all(values.data(), values.size(), MPI_FLOAT, ordered_sum_op<float>());
  }
  void sum_all(std::span<double> values) const override {
    sum_all(values.data(), values.size(), MPI_DOUBLE, ordered_sum_op<double>());
  }
  void max_all(std::span<double> values) const override {
    in_pieces(values.size(), [&](std::size_t at, int n) {
      MPI_Allreduce(MPI_IN_PLACE, values.data() + at, n, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
    });
  }
  void broadcast(std::span<double> values) const override {
    MPI_Bcast(values.data(), static_cast<int>(values.size()), MPI_DOUBLE, 0, MPI_COMM_WORLD);
  }
  void broadcast(std::vector<unsigned char>& bytes, int root) const override {
    unsigned long long size = bytes.size();
    MPI_Bcast(&size, 1, MPI_UNSIGNED_LONG_LONG, root, MPI_COMM_WORLD);
    bytes.resize(size);
    in_pieces(bytes.size(), [&](std::size_t at, int n) {
      MPI_Bcast(bytes.data() + at, n, MPI_UNSIGNED_CHAR, root, MPI_COMM_WORLD);
    });
  }
  [[nodiscard]] std::vector<std::vector<unsigned char>> exchange(
      const std::vector<std::vector<unsigned char>>& to) const override {
    const auto n = static_cast<std::size_t>(size_);
    if (to.size() != n) throw std::logic_error("Job::exchange: one entry per rank");
    std::vector<unsigned long long> sizes(n), incoming(n);
    for (std::size_t r = 0; r < n; ++r) sizes[r] = r == static_cast<std::size_t>(rank_) ? 0 : to[r].size();
    MPI_Alltoall(sizes.data(), 1, MPI_UNSIGNED_LONG_LONG, incoming.data(), 1, MPI_UNSIGNED_LONG_LONG, MPI_COMM_WORLD);
    std::vector<std::vector<unsigned char>> from(n);
    std::vector<MPI_Request> requests;
    for (std::size_t r = 0; r < n; ++r) {
      from[r].resize(incoming[r]);
      in_pieces(from[r].size(), [&](std::size_t at, int count) {
        requests.emplace_back();
        MPI_Irecv(from[r].data() + at, count, MPI_UNSIGNED_CHAR, static_cast<int>(r), 0, MPI_COMM_WORLD,
                  &requests.back());
      });
    }
    for (std::size_t r = 0; r < n; ++r) {
      in_pieces(sizes[r], [&](std::size_t at, int count) {
        requests.emplace_back();
        MPI_Isend(to[r].data() + at, count, MPI_UNSIGNED_CHAR, static_cast<int>(r), 0, MPI_COMM_WORLD,
                  &requests.back());
      });
    }
    MPI_Waitall(static_cast<int>(requests.size()), requests.data(), MPI_STATUSES_IGNORE);
    return from;
  }
  [[noreturn]] void abort(int code) const override {
    MPI_Abort(MPI_COMM_WORLD, code);
    std::exit(code);  // not reached
  }

 private:
  // Reduces count elements of `type` with `op` to rank 0 (in place there).
  void to_root(void* data, std::size_t count, MPI_Datatype type, MPI_Op op) const {
    int bytes = 0;
    MPI_Type_size(type, &bytes);
    auto* at0 = static_cast<unsigned char*>(data);
    in_pieces(count, [&](std::size_t at, int n) {
      void* piece = at0 + at * static_cast<std::size_t>(bytes);
      if (rank_ == 0) {
        MPI_Reduce(MPI_IN_PLACE, piece, n, type, op, 0, MPI_COMM_WORLD);
      } else {
        MPI_Reduce(piece, nullptr, n, type, op, 0, MPI_COMM_WORLD);
      }
    });
  }
  // Reduced in rank order by `sum` to rank 0, then broadcast: the same bits everywhere.
  void sum_all(void* data, std::size_t count, MPI_Datatype type, MPI_Op sum) const {
    to_root(data, count, type, sum);
    int bytes = 0;
    MPI_Type_size(type, &bytes);
    auto* at0 = static_cast<unsigned char*>(data);
    in_pieces(count,
              [&](std::size_t at, int n) { MPI_Bcast(at0 + at * static_cast<std::size_t>(bytes), n, type, 0, MPI_COMM_WORLD); });
  }
  // MPI types and operations, made once (they live until MPI_Finalize).
  static MPI_Datatype soft_pixel_type() {
    static MPI_Datatype type = [] {
      MPI_Datatype t;
      MPI_Type_contiguous(3, MPI_FLOAT, &t);
      MPI_Type_commit(&t);
      return t;
    }();
    return type;
  }
  static MPI_Op merge_op() {
    static MPI_Op op = [] {
      MPI_Op o;
      // inout[i] = in[i] (the lower ranks) merged with inout[i].
      MPI_Op_create(
          [](void* in, void* inout, int* len, MPI_Datatype*) {
            const auto* a = static_cast<const splat::SoftPixel*>(in);
            auto* b = static_cast<splat::SoftPixel*>(inout);
            for (int i = 0; i < *len; ++i) b[i] = splat::merge_soft_pixel(a[i], b[i]);
          },
          /*commute=*/0, &o);
      return o;
    }();
    return op;
  }
  template <class T>
  static MPI_Op ordered_sum_op() {
    static MPI_Op op = [] {
      MPI_Op o;
      MPI_Op_create(
          [](void* in, void* inout, int* len, MPI_Datatype*) {
            const auto* a = static_cast<const T*>(in);
            auto* b = static_cast<T*>(inout);
            for (int i = 0; i < *len; ++i) b[i] = a[i] + b[i];
          },
          /*commute=*/0, &o);
      return o;
    }();
    return op;
  }

  // call(at, n) for consecutive pieces of [0, count) of at most 2^30 elements:
  // MPI counts are int.
  template <class Call>
  static void in_pieces(std::size_t count, const Call& call) {
    constexpr std::size_t kPiece = std::size_t{1} << 30;
    for (std::size_t at = 0; at < count; at += kPiece) call(at, static_cast<int>(std::min(kPiece, count - at)));
  }

  int rank_ = 0, size_ = 1;
};
#endif

// A positive count from the environment variable `name`, or nullopt.
std::optional<int> env_count(const char* name) {
  const char* text = std::getenv(name);
  if (!text || !*text) return std::nullopt;
  int n = 0;
  const char* end = text + std::strlen(text);
  const auto [at, error] = std::from_chars(text, end, n);
  if (error != std::errc{} || at != end || n < 1) return std::nullopt;
  return n;
}

}  // namespace

int launched_ranks() {
  // Open MPI's mpirun; MPICH/Hydra and Slurm's PMI; a Slurm job step (srun), not
  // the batch script itself (which has SLURM_NTASKS but no step).
  if (const auto n = env_count("OMPI_COMM_WORLD_SIZE")) return *n;
  if (const auto n = env_count("PMI_SIZE")) return *n;
  if (std::getenv("SLURM_STEP_ID") != nullptr) {
    if (const auto n = env_count("SLURM_STEP_NUM_TASKS")) return *n;
  }
  return 1;
}

const Job& job() {
  static std::once_flag once;
  static std::unique_ptr<Job> the_job;
  static std::string failure;
  std::call_once(once, [] {
    const int ranks = launched_ranks();
    if (ranks <= 1) {
      the_job = std::make_unique<SingleProcess>();
      return;
    }
#if HISNEGS_HAVE_MPI
    try {
      the_job = std::make_unique<MpiWorld>();
    } catch (const std::exception& e) {
      failure = e.what();
      the_job = std::make_unique<SingleProcess>();
    }
#else
    failure = "launched as " + std::to_string(ranks) +
              " ranks, but this hisnegs was built without MPI: each rank would do the whole work; rebuild with "
              "MPI (Debian: libopenmpi-dev) or run one process";
    the_job = std::make_unique<SingleProcess>();
#endif
  });
  if (!failure.empty()) throw io::InputError(failure);
  return *the_job;
}

void open_on_every_rank(const Job& job, const std::function<void()>& open) {
  if (!job.distributed()) {
    open();
    return;
  }
  std::exception_ptr failure;
  try {
    open();
  } catch (...) {
    failure = std::current_exception();
  }
  double failed[1] = {failure ? 1.0 : 0.0};
  job.sum_all(failed);
  if (failure) std::rethrow_exception(failure);
  if (failed[0] > 0) {
    // Ended by the failing rank's MPI_Abort; a barrier it never reaches holds us.
    job.barrier();
    job.abort(2);  // not reached unless the failing rank exits without aborting
  }
}

std::string rank_prefix(const Job& job) {
  return job.distributed() ? "rank " + std::to_string(job.rank()) + " of " + std::to_string(job.size()) + ": " : "";
}

}  // namespace hisnegs::apps
