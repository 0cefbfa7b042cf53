// SPDX-License-Identifier: Apache-2.0
// The parts of the SplatRenderer interface common to the back ends: settings,
// view conversion, the flat parameter view, and the back-end factory.
#include "splat/splat_renderer.hpp"

#include <cstdint>
#include <stdexcept>
#include <vector>

#include "io/error.hpp"
#if HISNEGS_HAVE_CUDA
#include "splat/cuda/splat_cuda.hpp"
#endif

namespace hisnegs::splat {

std::unique_ptr<SplatRenderer> make_cpu_splat_renderer();  // splat_cpu.cpp

#if HISNEGS_HAVE_CUDA
namespace {

// SplatRenderer over the C++17 CUDA interface.
class CudaSplatRenderer final : public SplatRenderer {
 public:
  void forward(std::span<const float> params, const Intrinsics& K, const CameraView& view,
               const SplatSettings& settings, std::span<float> image) override {
    if (params.size() % gmf::kGaussianParamCount != 0 || image.size() != static_cast<std::size_t>(K.width) * K.height ||
        (!settings.floor.empty() && settings.floor.size() != image.size())) {
      throw std::invalid_argument("splat: parameter, image or floor span of the wrong size");
    }
    count_ = params.size() / gmf::kGaussianParamCount;
    pixels_ = image.size();
    soft_ = settings.soft();
    differentiable_ = soft_ || settings.keep_argmax;
    // Hard mode: the floor is a term of the kernels' max. Soft mode: max(soft MIP,
    // floor) here, and no gradient where the floor wins (as the CPU back end).
    const bool soft_floor = settings.soft() && !settings.floor.empty();
    splatter_.forward(params.data(), count_, make_splat_view<float>(K, view), settings, image.data(),
                      settings.floor.empty() || soft_floor ? nullptr : settings.floor.data());
    floor_above_.clear();
    if (soft_floor) {
      floor_above_.resize(pixels_);
      for (std::size_t i = 0; i < pixels_; ++i) {
        floor_above_[i] = settings.floor[i] > image[i] ? 1 : 0;
        if (floor_above_[i]) image[i] = settings.floor[i];
      }
    }
    stats_.visible = splatter_.visible();
    stats_.tile_entries = splatter_.tile_entries();
    stats_.skipped_terms = splatter_.skipped_terms();
  }
  void backward(std::span<const float> dL_dimage, std::span<float> dL_dparams, std::span<float> screen_grad) override {
    if (!differentiable_) {
      throw std::logic_error("splat: backward needs a soft-MIP forward, or a hard one with keep_argmax");
    }
    if (dL_dimage.size() != pixels_ || dL_dparams.size() != count_ * gmf::kGaussianParamCount ||
        (!screen_grad.empty() && screen_grad.size() != count_)) {
      throw std::invalid_argument("splat: backward spans do not match the last forward");
    }
    if (!floor_above_.empty()) {  // no gradient where the floor won the max
      masked_dL_.assign(dL_dimage.begin(), dL_dimage.end());
      for (std::size_t i = 0; i < masked_dL_.size(); ++i) {
        if (floor_above_[i]) masked_dL_[i] = 0.0f;
      }
      dL_dimage = masked_dL_;
    }
    splatter_.backward(dL_dimage.data(), dL_dparams.data(), screen_grad.empty() ? nullptr : screen_grad.data());
  }
  void soft_state(std::span<float> m, std::span<float> S) const override {
    if (!soft_ || m.size() != pixels_ || S.size() != pixels_) {
      throw std::logic_error("splat: soft_state needs a soft-MIP forward of the spans' size");
    }
    splatter_.soft_state(m.data(), S.data());
  }
  [[nodiscard]] const SplatFrameStats& stats() const override { return stats_; }
  [[nodiscard]] Backend backend() const override { return Backend::kCuda; }

 private:
  std::vector<std::uint8_t> floor_above_;  // soft mode with a floor: the floor won the max
  std::vector<float> masked_dL_;
  cuda::CudaSplatter splatter_;
  std::size_t count_ = 0, pixels_ = 0;
  bool soft_ = true;
  bool differentiable_ = true;  // soft, or hard with keep_argmax
  SplatFrameStats stats_;
};

}  // namespace
#endif

SplatSettings SplatSettings::from(const SplatOptions& options) {
  SplatSettings s;
  s.mode = options.mode;
  s.beta = static_cast<float>(options.beta);
  s.cutoff = static_cast<float>(options.mahalanobis_cutoff);
  s.low_pass = static_cast<float>(options.low_pass);
  s.skip_log_weight = static_cast<float>(options.skip_log_weight);
  return s;
}

template <class T>
ViewParams<T> make_splat_view(const Intrinsics& K, const CameraView& view) {
  ViewParams<T> p{};
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) p.R[3 * r + c] = static_cast<T>(view.R_cam_from_world(r, c));
    p.t[r] = static_cast<T>(view.t_cam_from_world[r]);
  }
  p.fx = static_cast<T>(K.fx);
  p.fy = static_cast<T>(K.fy);
  p.cx = static_cast<T>(K.cx);
  p.cy = static_cast<T>(K.cy);
  p.near_z = static_cast<T>(K.near);
  p.far_z = static_cast<T>(K.far);
  p.width = K.width;
  p.height = K.height;
  return p;
}
template ViewParams<float> make_splat_view<float>(const Intrinsics&, const CameraView&);
template ViewParams<double> make_splat_view<double>(const Intrinsics&, const CameraView&);

std::unique_ptr<SplatRenderer> make_splat_renderer(Backend backend) {
  if (backend == Backend::kCpu) return make_cpu_splat_renderer();
#if HISNEGS_HAVE_CUDA
  const CudaDeviceInfo& info = cuda_device_info();
  if (!info.available) throw io::InputError("backend cuda: no usable CUDA device (" + info.reason + ")");
  return std::make_unique<CudaSplatRenderer>();
#else
  throw io::InputError("backend cuda: this build of hisnegs has no CUDA back end (configure with -DHISNEGS_CUDA=ON)");
#endif
}

}  // namespace hisnegs::splat
