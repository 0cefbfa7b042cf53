// SPDX-License-Identifier: Apache-2.0
// The stage-2 training losses of report §6 (Eq. 11-15) on H x W images, each with
// its exact gradient. Not the trainer, the optimizer or the renderer's backward.
#pragma once

#include <cstddef>
#include <span>
#include <vector>

namespace hisnegs::splat {

struct TrainOptions;

// Images: `width` x `height` row-major spans (pixel (column c, row r) at r*width + c),
// values nominally in [0, 1]. `render` is the prediction P, `target` the ground
// truth G. Every loss returns its UNWEIGHTED value and, when `grad` is not empty
// (it must then hold width*height values), ADDS `weight` × ∂loss/∂render into it.
// Each loss comes as a float overload (the trainer) and a double overload (the
// reference the tests check against finite differences); both compute in double.
// The image losses run in parallel (TBB) over fixed blocks whose partial sums are
// added in order, so values and gradients are the same bits for any thread count.
// Throws std::invalid_argument on mismatched sizes or invalid parameters.

// Scratch memory the image losses reuse, so a trainer's step allocates nothing once
// it has grown to the image size. One per concurrent caller; contents mean nothing
// between calls.
class LossWorkspace {
 public:
  // `count` doubles, valid until the next call; grows, never shrinks.
  std::span<double> doubles(std::size_t count);

 private:
  std::vector<double> storage_;
};

// Eq. 11, the report's weights: L = (1/N) Σ_i w_i (p_i − g_i)², w_i = 1 + (w_fg − 1) g_i,
// N = width*height. (The report weighs by the target intensity itself, not by a
// threshold: the brightest pixels get w_fg, the background 1.)
double weighted_mse(std::span<const float> render, std::span<const float> target, int width, int height,
                    double foreground_weight, double weight, std::span<float> grad);
double weighted_mse(std::span<const double> render, std::span<const double> target, int width, int height,
                    double foreground_weight, double weight, std::span<double> grad);

// Eq. 12: L = 1 − mean SSIM, exactly CONVENTIONS "Metrics" (scikit-image
// structural_similarity, gaussian_weights=True, sigma 1.5, truncate 3.5 → 11 taps,
// use_sample_covariance=False, data_range 1): the SSIM map is averaged over the pixels
// at least 5 from every border, whose windows lie inside the image, so the filter's
// border mode never matters. Requires width, height >= 11. So 1 − L is the metric.
double ssim_loss(std::span<const float> render, std::span<const float> target, int width, int height, double weight,
                 std::span<float> grad, LossWorkspace& workspace);
double ssim_loss(std::span<const double> render, std::span<const double> target, int width, int height, double weight,
                 std::span<double> grad, LossWorkspace& workspace);

// Eq. 13, ‖∇P − ∇G‖² as the mean squared difference of Sobel responses:
// L = (1/N) Σ_p [(S_x * (P − G))_p² + (S_y * (P − G))_p²], with the unnormalised 3x3
// Sobel kernels S_x = [1 2 1]ᵀ[−1 0 1] (x along columns), S_y = S_xᵀ, and replicated
// borders (no edge appears at the image border).
double edge_loss(std::span<const float> render, std::span<const float> target, int width, int height, double weight,
                 std::span<float> grad, LossWorkspace& workspace);
double edge_loss(std::span<const double> render, std::span<const double> target, int width, int height, double weight,
                 std::span<double> grad, LossWorkspace& workspace);

// The differentiable intensity histogram of Eq. 14. A pixel of value x puts mass
// κ_b(x) = Δ/(√(2π) h) exp(−½ ((c_b − x)/h)²) into bin b, centre c_b = (b + ½) Δ,
// Δ = 1/bins (≈ 1 in all for x well inside [0, 1]); m_b = (1/N) Σ_i κ_b(x_i) and
// p_b = (m_b + ε) / Σ_b' (m_b' + ε).
struct SoftHistogramOptions {
  int bins = 64;                  // number of bins on [0, 1], [2, 4096]
  double bandwidth = 1.0 / 64.0;  // kernel standard deviation h, intensity units, > 0
  double epsilon = 1e-6;          // ε added to every bin's mass (keeps the log finite), > 0

  void validate() const;
};

// Eq. 14 as the report writes it: L = KL(hist(P) ‖ hist(G)) = Σ_b p_b log(p_b / q_b),
// p the render's soft histogram, q the target's. Zero when both histograms are equal
// (blind to where pixels are). Throws std::invalid_argument on a non-finite render pixel.
double intensity_kl_loss(std::span<const float> render, std::span<const float> target, int width, int height,
                         const SoftHistogramOptions& histogram, double weight, std::span<float> grad,
                         LossWorkspace& workspace);
double intensity_kl_loss(std::span<const double> render, std::span<const double> target, int width, int height,
                         const SoftHistogramOptions& histogram, double weight, std::span<double> grad,
                         LossWorkspace& workspace);

// Eq. 15 without its λ: L = Σ_k Σ_axis [max(0, s_min − s) + max(0, s − s_max)],
// s = exp(log-scale), SUMMED over Gaussians as the report writes it (pass
// weight = λ/K for a mean). `params` is 11 K values in gmf::GaussianParam order;
// `grad` (11 K, or empty) gets weight × ∂L/∂log-scale (−s below s_min, +s above s_max,
// 0 inside and at the kinks). Requires 0 < s_min < s_max.
double scale_regularizer(std::span<const float> params, double s_min, double s_max, double weight,
                         std::span<float> grad);
double scale_regularizer(std::span<const double> params, double s_min, double s_max, double weight,
                         std::span<double> grad);

// Weights of the image terms of Eq. 16. The default is plain MSE (w_fg = 1, only
// the WMSE term); image_loss_weights(train) gives the configured objective.
struct ImageLossWeights {
  double foreground_weight = 1.0;  // w_fg of Eq. 11, >= 1
  double wmse = 1.0;               // weight of Eq. 11 (1 in Eq. 16), >= 0
  double ssim = 0.0;               // λ_SSIM, >= 0
  double edge = 0.0;               // λ_edge, >= 0
  double intensity = 0.0;          // λ_int, >= 0
  SoftHistogramOptions histogram;  // the soft histogram of the intensity term
};

// foreground_weight, lambda_ssim, lambda_edge, lambda_intensity of `train`.
ImageLossWeights image_loss_weights(const TrainOptions& train);

// Each term's unweighted value (NaN for a term of weight 0, which is not evaluated)
// and total = Σ weight × value over the evaluated terms.
struct ImageLossTerms {
  double wmse = 0;
  double ssim = 0;
  double edge = 0;
  double intensity = 0;
  double total = 0;
};

// The image losses as a registry: each entry names a term, where its weight and
// its value live, and computes it with its gradient (a float function for the
// trainer, a double one for the reference the tests check against finite
// differences). combined_image_loss and the weight checks iterate it, in its
// order; a new image loss is its function, a weight and a value field, and one
// entry here.
template <class T>
using ImageLossFunction = double (*)(std::span<const T> render, std::span<const T> target, int width, int height,
                                     const ImageLossWeights& weights, double weight, std::span<T> grad,
                                     LossWorkspace& workspace);
struct ImageLossEntry {
  const char* name;                   // as ImageLossWeights names it
  double ImageLossWeights::*weight;   // its weight (0: not evaluated)
  double ImageLossTerms::*value;      // where its unweighted value goes
  ImageLossFunction<float> of_float;
  ImageLossFunction<double> of_double;
};
[[nodiscard]] std::span<const ImageLossEntry> image_losses();

// The image part of Eq. 16 (everything but L_reg): adds ∂total/∂render into `grad`
// (or only evaluates when `grad` is empty).
ImageLossTerms combined_image_loss(std::span<const float> render, std::span<const float> target, int width, int height,
                                   const ImageLossWeights& weights, std::span<float> grad, LossWorkspace& workspace);
ImageLossTerms combined_image_loss(std::span<const double> render, std::span<const double> target, int width,
                                   int height, const ImageLossWeights& weights, std::span<double> grad,
                                   LossWorkspace& workspace);

}  // namespace hisnegs::splat
