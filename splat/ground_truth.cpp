// SPDX-License-Identifier: Apache-2.0
// render_ground_truth: per-view loop over the TBB or CUDA ray marcher.
#include "splat/ground_truth.hpp"

#include <memory>

#include "io/memory_limit.hpp"
#include "io/timer.hpp"
#include "splat/raymarch.hpp"
#if HISNEGS_HAVE_CUDA
#include "splat/cuda/raymarch_cuda.hpp"
#endif

namespace hisnegs::splat {

MipStack render_ground_truth(const io::Volume& volume, const io::WorldFrame& frame, const CameraSet& cameras,
                             const RaymarchOptions& options, Backend backend,
                             const std::function<void(int, int)>& progress) {
  const RayMarcher marcher(volume, frame, options);
  MipStack out;
  const Intrinsics& K = cameras.intrinsics;
  out.width = K.width;
  out.height = K.height;
  out.views = static_cast<int>(cameras.views.size());
  out.backend = backend;
  io::check_allocation("camera", 4.0 * K.width * K.height * static_cast<double>(out.views),
                       std::to_string(out.views) + " float32 views of " + std::to_string(K.width) + "x" +
                           std::to_string(K.height));
  out.pixels.resize(static_cast<std::size_t>(out.views) * K.width * K.height);
  const std::size_t frame_px = static_cast<std::size_t>(K.width) * K.height;
#if HISNEGS_HAVE_CUDA
  std::unique_ptr<cuda::CudaRayMarcher> gpu;
  if (backend == Backend::kCuda) {
    gpu = std::make_unique<cuda::CudaRayMarcher>(marcher.dense(), marcher.bricks(), marcher.params());
  }
#endif
  for (int i = 0; i < out.views; ++i) {
    const std::span<float> image(out.pixels.data() + i * frame_px, frame_px);
    io::Stopwatch watch;
#if HISNEGS_HAVE_CUDA
    if (gpu) {
      gpu->render(make_ray_view(K, cameras.views[i]), image.data(), image.size());
    } else {
      marcher.render(K, cameras.views[i], image);
    }
#else
    marcher.render(K, cameras.views[i], image);
#endif
    out.seconds_per_view.push_back(watch.elapsed());
    if (progress) progress(i + 1, out.views);
  }
  return out;
}

}  // namespace hisnegs::splat
