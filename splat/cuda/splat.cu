// SPDX-License-Identifier: Apache-2.0
// The CUDA splatting back end behind splat/cuda/splat_cuda.hpp: device buffers kept
// across frames, binning of (tile, Gaussian) pairs with CUB (scan, stable radix
// sort), the launches of splat_kernels.cuh, CUDA-event timing and the host copies.
// The kernels are in splat_kernels.cuh; all per-Gaussian math in splat_math.hpp.
#include <cuda_runtime.h>

#include <algorithm>
#include <climits>
#include <cstdint>
#include <cub/device/device_radix_sort.cuh>
#include <cub/device/device_scan.cuh>
#include <stdexcept>
#include <string>
#include <vector>

#include "splat/cuda/check.cuh"
#include "splat/cuda/device_buffer.cuh"
#include "splat/cuda/splat_cuda.hpp"
#include "splat/cuda/splat_kernels.cuh"

namespace hisnegs::splat::cuda {
namespace {

using gmf::kGaussianParamCount;
constexpr int kGaussianThreads = 256;    // preprocess / duplicate / range kernels
constexpr int kProjectionThreads = 128;  // projection backward (double, register heavy)

// Grows `buffer` to at least `count` elements (contents are not kept). Never
// shrinks, and grows by at least half, so once frame sizes settle no frame allocates.
template <class T>
void reserve(DeviceBuffer<T>& buffer, std::size_t count) {
  if (buffer.size() >= count) return;
  buffer.resize(std::max(count, buffer.size() + buffer.size() / 2));
}

unsigned int blocks_for(std::size_t items, int threads) {
  return static_cast<unsigned int>((items + threads - 1) / threads);
}

// Owner of one CUDA event (RAII, not copyable).
class Event {
 public:
  Event() { HISNEGS_CUDA_CHECK(cudaEventCreate(&event_)); }
  ~Event() {
    if (event_ != nullptr) cudaEventDestroy(event_);
  }
  Event(const Event&) = delete;
  Event& operator=(const Event&) = delete;
  void record() { HISNEGS_CUDA_CHECK(cudaEventRecord(event_)); }
  [[nodiscard]] cudaEvent_t get() const { return event_; }

 private:
  cudaEvent_t event_ = nullptr;
};

double elapsed_ms(const Event& from, const Event& to) {
  float ms = 0.0f;
  HISNEGS_CUDA_CHECK(cudaEventElapsedTime(&ms, from.get(), to.get()));
  return ms;
}

void require_device() {
  int count = 0;
  const cudaError_t err = cudaGetDeviceCount(&count);
  if (err != cudaSuccess) {
    cudaGetLastError();  // clear the error state for later callers
    throw std::runtime_error(std::string("CUDA splatting: no usable CUDA device: ") + cudaGetErrorString(err));
  }
  if (count == 0) throw std::runtime_error("CUDA splatting: no usable CUDA device: none found");
}

ViewParams<double> to_double(const ViewParams<float>& v) {
  ViewParams<double> d{};
  for (int i = 0; i < 9; ++i) d.R[i] = v.R[i];
  for (int i = 0; i < 3; ++i) d.t[i] = v.t[i];
  d.fx = v.fx;
  d.fy = v.fy;
  d.cx = v.cx;
  d.cy = v.cy;
  d.near_z = v.near_z;
  d.far_z = v.far_z;
  d.width = v.width;
  d.height = v.height;
  return d;
}

// Bits needed for tile ids 0 .. tiles − 1: the radix sort only looks at those
// above the 32 amplitude bits.
int tile_bits(std::size_t tiles) {
  int bits = 0;
  while ((std::size_t{1} << bits) < tiles) ++bits;
  return bits;
}

}  // namespace

struct CudaSplatter::Impl {
  // The last forward.
  bool has_forward = false;
  std::size_t count = 0, pixels = 0, tiles = 0;
  int tiles_x = 0;
  std::uint32_t entries = 0;
  ViewParams<float> view{};
  KernelSettings settings{};
  int visible = 0;
  std::int64_t skipped = 0;
  double forward_ms = 0.0, backward_ms = 0.0;

  // Device state, grown only when needed (reserve()).
  DeviceBuffer<float> params;                     // 11 K
  DeviceBuffer<Splat2D<float>> splats;            // K
  DeviceBuffer<TileRect> rects;                   // K
  DeviceBuffer<EllipseRows<float>> rows;          // K: each ellipse row by row, for the band walk
  DeviceBuffer<std::uint64_t> touched, offsets;   // K + 1: tiles per Gaussian, their exclusive scan
  DeviceBuffer<std::uint64_t> keys[2];            // entries: tile << 32 | amplitude key (sort double buffer)
  DeviceBuffer<std::uint32_t> ids[2];             // entries: Gaussian id
  const std::uint32_t* sorted_ids = nullptr;      // whichever of ids[] holds the sorted list
  DeviceBuffer<uint2> ranges;                     // tiles: [begin, end) into the sorted list
  DeviceBuffer<float> m, S, I;                    // pixels: softmax state kept for backward
  DeviceBuffer<std::int32_t> argmax;              // pixels: hard mode with keep_argmax
  DeviceBuffer<float> floor;                      // pixels: the background term (forward only)
  bool has_floor = false;
  DeviceBuffer<kernels::FrameCounters> counters;  // 1
  DeviceBuffer<unsigned char> cub_temp;
  DeviceBuffer<float> dL_dI;                    // pixels
  DeviceBuffer<float> grads2d;                  // 6 K: u, v, con_a, con_b, con_c, amplitude
  DeviceBuffer<float> dL_dparams, screen_grad;  // 11 K, K
  std::vector<float> host_scratch;

  Event start, scan_done, sort_start, stop;

  kernels::TileParams tile_params() const {
    return {view.width, view.height, tiles_x, settings, has_floor ? floor.data() : nullptr};
  }
  void bin();
};

CudaSplatter::CudaSplatter() {
  require_device();
  impl_ = std::make_unique<Impl>();
}

CudaSplatter::~CudaSplatter() = default;

// Sorts the (tile, Gaussian) pairs of the last preprocess into per-tile lists,
// amplitude descending. Reads back the number of pairs (the one host sync).
void CudaSplatter::Impl::bin() {
  std::uint64_t total = 0;
  if (count > 0) {
    HISNEGS_CUDA_CHECK(cudaMemcpy(&total, offsets.data() + count, sizeof(total), cudaMemcpyDeviceToHost));
  }
  if (total > UINT32_MAX) {
    throw std::runtime_error("CUDA splatting: " + std::to_string(total) +
                             " (tile, Gaussian) pairs exceed the 2^32 the tile ranges can index");
  }
  entries = static_cast<std::uint32_t>(total);
  for (int b = 0; b < 2; ++b) {
    reserve(keys[b], entries);
    reserve(ids[b], entries);
  }
  sort_start.record();
  sorted_ids = ids[0].data();
  if (entries == 0) return;
  kernels::duplicate_kernel<<<blocks_for(count, kGaussianThreads), kGaussianThreads>>>(
      splats.data(), rects.data(), rows.data(), offsets.data(), static_cast<int>(count), tiles_x,
      static_cast<std::uint32_t>(tiles), keys[0].data(), ids[0].data());
  HISNEGS_CUDA_CHECK_LAUNCH();
  // Stable LSD radix sort over the amplitude and tile bits: entries written in
  // Gaussian order keep it among equal amplitudes (deterministic lists).
  cub::DoubleBuffer<std::uint64_t> key_buffers(keys[0].data(), keys[1].data());
  cub::DoubleBuffer<std::uint32_t> id_buffers(ids[0].data(), ids[1].data());
  const int end_bit = 32 + tile_bits(tiles + 1);  // + 1: the duplicate kernel's "no tile" index
  std::size_t temp_bytes = 0;
  HISNEGS_CUDA_CHECK(
      cub::DeviceRadixSort::SortPairs(nullptr, temp_bytes, key_buffers, id_buffers, entries, 0, end_bit));
  reserve(cub_temp, std::max<std::size_t>(temp_bytes, 1));  // a null pointer would mean 'query'
  HISNEGS_CUDA_CHECK(
      cub::DeviceRadixSort::SortPairs(cub_temp.data(), temp_bytes, key_buffers, id_buffers, entries, 0, end_bit));
  sorted_ids = id_buffers.Current();
  kernels::tile_ranges_kernel<<<blocks_for(entries, kGaussianThreads), kGaussianThreads>>>(key_buffers.Current(),
                                                                                           entries, ranges.data());
  HISNEGS_CUDA_CHECK_LAUNCH();
}

namespace {

void check_forward_arguments(const float* params, std::size_t count, const ViewParams<float>& view,
                             const float* image) {
  if (count > static_cast<std::size_t>(INT_MAX)) {
    throw std::invalid_argument("CudaSplatter::forward: " + std::to_string(count) + " Gaussians exceed INT_MAX");
  }
  if (image == nullptr || (count > 0 && params == nullptr)) {
    throw std::invalid_argument("CudaSplatter::forward: null parameter or image array");
  }
  if (view.width <= 0 || view.height <= 0) {
    throw std::invalid_argument("CudaSplatter::forward: image size " + std::to_string(view.width) + "x" +
                                std::to_string(view.height) + " is empty");
  }
}

}  // namespace

void CudaSplatter::forward(const float* params, std::size_t count, const ViewParams<float>& view,
                           const KernelSettings& settings, float* image, const float* floor) {
  Impl& d = *impl_;
  check_forward_arguments(params, count, view, image);
  d.has_forward = false;
  d.count = count;
  d.view = view;
  d.settings = settings;
  d.tiles_x = (view.width + kTileSize - 1) / kTileSize;
  const int tiles_y = (view.height + kTileSize - 1) / kTileSize;
  d.tiles = static_cast<std::size_t>(d.tiles_x) * tiles_y;
  d.pixels = static_cast<std::size_t>(view.width) * view.height;

  reserve(d.params, kGaussianParamCount * count);
  reserve(d.splats, count);
  reserve(d.rects, count);
  reserve(d.rows, count);
  reserve(d.touched, count + 1);
  reserve(d.offsets, count + 1);
  reserve(d.ranges, d.tiles + 1);  // + 1: where the "no tile" entries land (never read)
  reserve(d.m, d.pixels);
  reserve(d.S, d.pixels);
  reserve(d.I, d.pixels);
  const bool keep_argmax = !settings.soft() && settings.keep_argmax;
  if (keep_argmax) reserve(d.argmax, d.pixels);
  reserve(d.counters, 1);
  d.has_floor = floor != nullptr;
  if (d.has_floor) {
    reserve(d.floor, d.pixels);
    HISNEGS_CUDA_CHECK(cudaMemcpy(d.floor.data(), floor, d.pixels * sizeof(float), cudaMemcpyHostToDevice));
  }
  if (count > 0) {
    HISNEGS_CUDA_CHECK(
        cudaMemcpy(d.params.data(), params, kGaussianParamCount * count * sizeof(float), cudaMemcpyHostToDevice));
  }

  // 1. Projection and tile counts, their exclusive scan.
  d.start.record();
  HISNEGS_CUDA_CHECK(cudaMemset(d.counters.data(), 0, sizeof(kernels::FrameCounters)));
  HISNEGS_CUDA_CHECK(cudaMemset(d.ranges.data(), 0, (d.tiles + 1) * sizeof(uint2)));
  if (count > 0) {
    kernels::preprocess_kernel<<<blocks_for(count, kGaussianThreads), kGaussianThreads>>>(
        d.params.data(), static_cast<int>(count), view, settings.cutoff, settings.low_pass, d.splats.data(),
        d.rects.data(), d.rows.data(), d.touched.data(), d.counters.data());
    HISNEGS_CUDA_CHECK_LAUNCH();
    std::size_t temp_bytes = 0;
    HISNEGS_CUDA_CHECK(
        cub::DeviceScan::ExclusiveSum(nullptr, temp_bytes, d.touched.data(), d.offsets.data(), count + 1));
    reserve(d.cub_temp, std::max<std::size_t>(temp_bytes, 1));
    HISNEGS_CUDA_CHECK(
        cub::DeviceScan::ExclusiveSum(d.cub_temp.data(), temp_bytes, d.touched.data(), d.offsets.data(), count + 1));
  }
  d.scan_done.record();

  // 2. Binning (the timing skips its host read-back of the pair count).
  d.bin();

  // 3. Rasterization, one block per tile.
  const dim3 block(kTileSize, kTileSize);
  const unsigned int grid = static_cast<unsigned int>(d.tiles);
  if (settings.soft()) {
    kernels::forward_kernel<true><<<grid, block>>>(d.ranges.data(), d.sorted_ids, d.splats.data(), d.tile_params(),
                                                   d.m.data(), d.S.data(), d.I.data(), nullptr, d.counters.data());
  } else {
    kernels::forward_kernel<false><<<grid, block>>>(d.ranges.data(), d.sorted_ids, d.splats.data(), d.tile_params(),
                                                    d.m.data(), d.S.data(), d.I.data(),
                                                    keep_argmax ? d.argmax.data() : nullptr, d.counters.data());
  }
  HISNEGS_CUDA_CHECK_LAUNCH();
  d.stop.record();
  HISNEGS_CUDA_CHECK(cudaEventSynchronize(d.stop.get()));
  d.forward_ms = elapsed_ms(d.start, d.scan_done) + elapsed_ms(d.sort_start, d.stop);

  kernels::FrameCounters counters{};
  d.counters.download(&counters, 1);
  d.visible = static_cast<int>(counters.visible);
  d.skipped = static_cast<std::int64_t>(counters.skipped);
  d.I.download(image, d.pixels);
  d.has_forward = true;
}

void CudaSplatter::backward(const float* dL_dimage, float* dL_dparams, float* screen_grad) {
  Impl& d = *impl_;
  const bool hard = !d.settings.soft();
  if (!d.has_forward || (hard && !d.settings.keep_argmax)) {
    throw std::logic_error(
        "CudaSplatter::backward: needs a successful soft-MIP forward, or a hard one with keep_argmax, first");
  }
  if (dL_dimage == nullptr || (d.count > 0 && dL_dparams == nullptr)) {
    throw std::invalid_argument("CudaSplatter::backward: null gradient array");
  }
  const std::size_t count = d.count;
  reserve(d.dL_dI, d.pixels);
  reserve(d.grads2d, 6 * count);
  reserve(d.dL_dparams, kGaussianParamCount * count);
  reserve(d.screen_grad, count);
  HISNEGS_CUDA_CHECK(cudaMemcpy(d.dL_dI.data(), dL_dimage, d.pixels * sizeof(float), cudaMemcpyHostToDevice));

  d.start.record();
  if (count > 0) HISNEGS_CUDA_CHECK(cudaMemset(d.grads2d.data(), 0, 6 * count * sizeof(float)));
  // 1. Per-Gaussian sums of the 2D gradients over every pixel it touches.
  if (hard && d.pixels > 0) {
    kernels::hard_backward_kernel<<<blocks_for(d.pixels, kGaussianThreads), kGaussianThreads>>>(
        d.splats.data(), d.argmax.data(), d.dL_dI.data(), d.view.width, d.view.height, d.grads2d.data());
    HISNEGS_CUDA_CHECK_LAUNCH();
  } else if (d.entries > 0) {
    kernels::backward_kernel<<<static_cast<unsigned int>(d.tiles), dim3(kTileSize, kTileSize)>>>(
        d.ranges.data(), d.sorted_ids, d.splats.data(), d.tile_params(), d.m.data(), d.S.data(), d.I.data(),
        d.dL_dI.data(), d.grads2d.data());
    HISNEGS_CUDA_CHECK_LAUNCH();
  }
  // 2. Through the projection to the 11 parameters, in double (as the CPU back end).
  if (count > 0) {
    kernels::projection_backward_kernel<<<blocks_for(count, kProjectionThreads), kProjectionThreads>>>(
        d.params.data(), static_cast<int>(count), to_double(d.view), double(d.settings.cutoff),
        double(d.settings.low_pass), d.splats.data(), d.grads2d.data(), d.dL_dparams.data(),
        screen_grad != nullptr ? d.screen_grad.data() : nullptr);
    HISNEGS_CUDA_CHECK_LAUNCH();
  }
  d.stop.record();
  HISNEGS_CUDA_CHECK(cudaEventSynchronize(d.stop.get()));
  d.backward_ms = elapsed_ms(d.start, d.stop);
  if (count == 0) return;

  // The interface adds into the caller's arrays.
  d.host_scratch.resize(kGaussianParamCount * count);
  d.dL_dparams.download(d.host_scratch.data(), kGaussianParamCount * count);
  for (std::size_t i = 0; i < kGaussianParamCount * count; ++i) dL_dparams[i] += d.host_scratch[i];
  if (screen_grad != nullptr) {
    d.screen_grad.download(d.host_scratch.data(), count);
    for (std::size_t k = 0; k < count; ++k) screen_grad[k] += d.host_scratch[k];
  }
}

void CudaSplatter::soft_state(float* m, float* S) const {
  const Impl& d = *impl_;
  if (!d.has_forward || !d.settings.soft()) {
    throw std::logic_error("CudaSplatter::soft_state: needs a successful soft-MIP forward first");
  }
  d.m.download(m, d.pixels);
  d.S.download(S, d.pixels);
}

int CudaSplatter::visible() const { return impl_->visible; }
std::int64_t CudaSplatter::tile_entries() const { return impl_->entries; }
std::int64_t CudaSplatter::skipped_terms() const { return impl_->skipped; }
double CudaSplatter::last_forward_ms() const { return impl_->forward_ms; }
double CudaSplatter::last_backward_ms() const { return impl_->backward_ms; }

}  // namespace hisnegs::splat::cuda
