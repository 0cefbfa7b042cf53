// Trainer: the epoch loop, Adam, density control (Eq. 17) and the state file; the
// checkpoint pair (epoch_NNNNN.ply + state_NNNNN.bin + latest) and resume.
#include "splat/trainer.hpp"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <limits>
#include <numbers>
#include <numeric>
#include <sstream>
#include <stdexcept>

#include "io/atomic_file.hpp"
#include "io/fault_injection.hpp"
#include "io/error.hpp"
#include "io/tiff_stack.hpp"
#include "io/timer.hpp"
#include "splat/metrics.hpp"

namespace hisnegs::splat {
namespace {

constexpr std::size_t kP = gmf::kGaussianParamCount;
constexpr double kAdamBeta1 = 0.9;
constexpr double kAdamBeta2 = 0.999;
constexpr double kAdamEpsilon = 1e-15;

// Parameter groups in gmf::GaussianParam order: 3 means, 3 log-scales, 4 quaternion, 1 logit.
constexpr std::array<int, kP> kGroupOf = {0, 0, 0, 1, 1, 1, 2, 2, 2, 2, 3};

std::uint64_t fnv1a(const void* bytes, std::size_t size) {
  std::uint64_t h = 1469598103934665603ull;
  const auto* p = static_cast<const unsigned char*>(bytes);
  for (std::size_t i = 0; i < size; ++i) h = (h ^ p[i]) * 1099511628211ull;
  return h;
}

// "name=value" lines of every train option (doubles with 17 digits, so equal text = equal value).
std::string options_text(TrainOptions options) {
  std::ostringstream s;
  s.precision(17);
  options.visit([&](std::string_view name, const auto& value, auto&&...) { s << name << '=' << value << '\n'; });
  return s.str();
}

// The state file: little-endian binary (this build only runs on little-endian hosts).
static_assert(std::endian::native == std::endian::little, "the training state file is little-endian");
constexpr char kStateMagic[8] = {'H', 'N', 'G', 'T', 'R', 'N', 'S', '1'};

class Writer {
 public:
  template <class T>
  void put(const T& value) {
    static_assert(std::is_trivially_copyable_v<T>);
    bytes_.append(reinterpret_cast<const char*>(&value), sizeof(T));
  }
  template <class T>
  void put_array(std::span<const T> values) {
    put<std::uint64_t>(values.size());
    bytes_.append(reinterpret_cast<const char*>(values.data()), values.size_bytes());
  }
  void put_string(const std::string& text) { put_array(std::span<const char>(text)); }
  std::string take() { return std::move(bytes_); }

 private:
  std::string bytes_;
};

class Reader {
 public:
  Reader(std::string_view bytes, const std::string& source) : bytes_(bytes), source_(source) {}
  template <class T>
  T get() {
    T value;
    need(sizeof(T));
    std::memcpy(&value, bytes_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return value;
  }
  template <class T>
  std::vector<T> get_array(std::size_t expected) {
    const auto n = get<std::uint64_t>();
    if (n != expected) fail("array of " + std::to_string(n) + " values, expected " + std::to_string(expected));
    std::vector<T> values(n);
    need(n * sizeof(T));
    std::memcpy(values.data(), bytes_.data() + at_, n * sizeof(T));
    at_ += n * sizeof(T);
    return values;
  }
  std::string get_string() {
    const auto n = get<std::uint64_t>();
    need(n);
    std::string text(bytes_.substr(at_, n));
    at_ += n;
    return text;
  }
  [[nodiscard]] bool done() const { return at_ == bytes_.size(); }
  [[noreturn]] void fail(const std::string& what) const { io::fail_input(source_, "training state: " + what); }

 private:
  void need(std::size_t n) const {
    if (n > bytes_.size() - at_) fail("truncated");
  }
  std::string_view bytes_;
  std::string source_;
  std::size_t at_ = 0;
};


std::string epoch_tag(int epoch) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%05d", epoch);
  return buf;
}

}  // namespace

std::span<const float> TrainingData::image(int i) const {
  const std::size_t n = static_cast<std::size_t>(intrinsics.width) * intrinsics.height;
  return std::span<const float>(images).subspan(static_cast<std::size_t>(i) * n, n);
}

void TrainingData::check() const {
  if (views.empty()) throw std::invalid_argument("TrainingData: no views");
  const std::size_t n = static_cast<std::size_t>(intrinsics.width) * intrinsics.height;
  if (images.size() != views.size() * n) {
    throw std::invalid_argument("TrainingData: " + std::to_string(images.size()) + " pixels for " +
                                std::to_string(views.size()) + " views of " + std::to_string(intrinsics.width) +
                                "x" + std::to_string(intrinsics.height));
  }
}

TrainingData load_training_data(const std::filesystem::path& dir) {
  const std::filesystem::path cameras_path = dir / "cameras.json", mips_path = dir / "mips.tif";
  io::require_regular_file(cameras_path);
  io::require_regular_file(mips_path);
  CameraSet cameras = read_cameras_json(cameras_path);
  io::Volume stack = io::read_tiff_stack(mips_path);
  const Intrinsics& K = cameras.intrinsics;
  if (stack.nz != static_cast<int>(cameras.views.size())) {
    io::fail_input(mips_path, std::to_string(stack.nz) + " pages, but " + cameras_path.string() + " has " +
                                  std::to_string(cameras.views.size()) + " views");
  }
  if (stack.nx != K.width || stack.ny != K.height) {
    io::fail_input(mips_path, "pages of " + std::to_string(stack.nx) + "x" + std::to_string(stack.ny) + ", but " +
                                  cameras_path.string() + " gives " + std::to_string(K.width) + "x" +
                                  std::to_string(K.height));
  }
  TrainingData data;
  data.intrinsics = K;
  data.views = std::move(cameras.views);
  data.images = std::move(stack.voxels);
  return data;
}

double learning_rate(const TrainOptions& o, int epoch) {
  if (o.epochs <= 1) return o.lr_initial;
  const double t = std::clamp(static_cast<double>(epoch) / (o.epochs - 1), 0.0, 1.0);
  return o.lr_final + 0.5 * (o.lr_initial - o.lr_final) * (1.0 + std::cos(std::numbers::pi * t));
}

double soft_mip_beta(const TrainOptions& o, int epoch) {
  if (o.beta_warmup_epochs <= 0) return o.beta_end;
  const double t = std::min(1.0, static_cast<double>(epoch) / o.beta_warmup_epochs);
  return o.beta_start + (o.beta_end - o.beta_start) * t;
}

Trainer::Trainer(const TrainOptions& options, const SplatSettings& splat, TrainingData data,
                 std::vector<float> params, std::unique_ptr<SplatRenderer> renderer, double scene_scale)
    : options_(options),
      splat_(splat),
      data_(std::move(data)),
      params_(std::move(params)),
      renderer_(std::move(renderer)),
      scene_scale_(scene_scale),
      weights_(image_loss_weights(options)),
      rng_(options.seed) {
  options_.validate();
  data_.check();
  if (!renderer_) throw std::invalid_argument("Trainer: no renderer");
  if (splat_.mode != MipMode::kSoft) throw std::invalid_argument("Trainer: training needs splat.mode soft");
  if (params_.size() % kP != 0) throw std::invalid_argument("Trainer: params size is not a multiple of 11");
  if (const std::string bad = gmf::describe_non_finite<float>(params_, "value"); !bad.empty()) {
    throw std::invalid_argument("Trainer: " + bad + " of the initial model is not finite");
  }
  if (!(scene_scale_ > 0) || !std::isfinite(scene_scale_)) throw std::invalid_argument("Trainer: scene_scale must be > 0");
  const int edge = std::min(data_.intrinsics.width, data_.intrinsics.height);
  if (options_.crop_size > edge) {
    throw std::invalid_argument("Trainer: train.crop_size " + std::to_string(options_.crop_size) +
                                " exceeds the image (" + std::to_string(edge) + " pixels)");
  }
  m_.assign(params_.size(), 0.0f);
  v_.assign(params_.size(), 0.0f);
  resize_state(params_.size() / kP);
}

Trainer::~Trainer() = default;

void Trainer::resize_state(std::size_t K) {
  grad_accum_.assign(K, 0.0);
  grad_count_.assign(K, 0);
}

Trainer::StepSums Trainer::train_step(std::span<const int> view_indices) {
  if (view_indices.empty()) throw std::invalid_argument("Trainer::step: no views");
  SplatSettings settings = splat_;
  settings.beta = static_cast<float>(soft_mip_beta(options_, epoch_));
  const std::size_t K = params_.size() / kP;
  grad_.assign(params_.size(), 0.0f);
  view_screen_grad_.resize(K);
  StepSums sums;
  for (int i : view_indices) {
    if (i < 0 || i >= data_.count()) throw std::out_of_range("Trainer::step: view index " + std::to_string(i));
    Intrinsics intr = data_.intrinsics;
    std::span<const float> target = data_.image(i);
    if (options_.crop_size > 0) {
      // A random crop is the same pinhole camera with its principal point shifted.
      const int c = options_.crop_size;
      const int x0 = std::uniform_int_distribution<int>(0, intr.width - c)(rng_);
      const int y0 = std::uniform_int_distribution<int>(0, intr.height - c)(rng_);
      target_crop_.resize(static_cast<std::size_t>(c) * c);
      for (int r = 0; r < c; ++r) {
        std::copy_n(target.begin() + static_cast<std::ptrdiff_t>(y0 + r) * intr.width + x0, c,
                    target_crop_.begin() + static_cast<std::ptrdiff_t>(r) * c);
      }
      intr.cx -= x0;
      intr.cy -= y0;
      intr.width = intr.height = c;
      target = target_crop_;
    }
    const std::size_t N = static_cast<std::size_t>(intr.width) * intr.height;
    image_.resize(N);
    dimage_.assign(N, 0.0f);
    renderer_->forward(params_, intr, data_.views[static_cast<std::size_t>(i)], settings, image_);
    const ImageLossTerms terms =
        combined_image_loss(image_, target, intr.width, intr.height, weights_, dimage_, workspace_);
    std::fill(view_screen_grad_.begin(), view_screen_grad_.end(), 0.0f);
    renderer_->backward(dimage_, grad_, view_screen_grad_);
    for (std::size_t k = 0; k < K; ++k) {
      if (view_screen_grad_[k] > 0.0f) {
        grad_accum_[k] += static_cast<double>(view_screen_grad_[k]) * static_cast<double>(N);
        ++grad_count_[k];
      }
    }
    sums.loss += terms.total;
    sums.psnr += image_psnr(image_, target);
  }
  const auto B = static_cast<float>(view_indices.size());
  if (view_indices.size() > 1) {
    for (float& g : grad_) g /= B;
  }
  const double reg = options_.lambda_scale *
                     scale_regularizer(std::span<const float>(params_), options_.scale_min, options_.scale_max,
                                       options_.lambda_scale, grad_);
  sums.loss += static_cast<double>(view_indices.size()) * reg;
  if (!std::isfinite(sums.loss)) {
    throw std::runtime_error("training diverged: the loss is not finite in epoch " + std::to_string(epoch_ + 1) +
                             ", step " + std::to_string(step_ + 1));
  }
  if (const std::string bad = gmf::describe_non_finite<float>(grad_, "gradient"); !bad.empty()) {
    throw std::runtime_error("training diverged in epoch " + std::to_string(epoch_ + 1) + ", step " +
                             std::to_string(step_ + 1) + ": " + bad + " is not finite");
  }
  adam_update(grad_, learning_rate(options_, epoch_));
  if (const std::string bad = gmf::describe_non_finite<float>(params_, "value"); !bad.empty()) {
    throw std::runtime_error("training diverged in epoch " + std::to_string(epoch_ + 1) + ", step " +
                             std::to_string(step_) + ": the update made " + bad + " not finite");
  }
  return sums;
}

double Trainer::step(std::span<const int> view_indices) {
  return train_step(view_indices).loss / static_cast<double>(view_indices.size());
}

void Trainer::adam_update(std::span<const float> grad, double lr) {
  ++step_;
  const double t = static_cast<double>(step_);
  const double bc1 = 1.0 - std::pow(kAdamBeta1, t);
  const double bc2 = 1.0 - std::pow(kAdamBeta2, t);
  const std::array<double, 4> group_lr = {lr * options_.lr_means * scene_scale_, lr * options_.lr_log_scales,
                                          lr * options_.lr_rotation, lr * options_.lr_intensity};
  for (std::size_t i = 0; i < params_.size(); ++i) {
    const double g = grad[i];
    const double m = kAdamBeta1 * m_[i] + (1.0 - kAdamBeta1) * g;
    const double v = kAdamBeta2 * v_[i] + (1.0 - kAdamBeta2) * g * g;
    m_[i] = static_cast<float>(m);
    v_[i] = static_cast<float>(v);
    const double update = group_lr[kGroupOf[i % kP]] * (m / bc1) / (std::sqrt(v / bc2) + kAdamEpsilon);
    params_[i] = static_cast<float>(params_[i] - update);
  }
}

Trainer::Evaluation Trainer::evaluate() {
  SplatSettings settings = splat_;
  settings.beta = static_cast<float>(soft_mip_beta(options_, epoch_));
  const Intrinsics& intr = data_.intrinsics;
  image_.resize(static_cast<std::size_t>(intr.width) * intr.height);
  Evaluation e;
  const double reg = options_.lambda_scale * scale_regularizer(std::span<const float>(params_), options_.scale_min,
                                                               options_.scale_max, 0.0, std::span<float>());
  for (int i = 0; i < data_.count(); ++i) {
    renderer_->forward(params_, intr, data_.views[static_cast<std::size_t>(i)], settings, image_);
    e.loss += combined_image_loss(image_, data_.image(i), intr.width, intr.height, weights_, std::span<float>(),
                                  workspace_)
                  .total +
              reg;
    e.psnr += image_psnr(image_, data_.image(i));
  }
  e.loss /= data_.count();
  e.psnr /= data_.count();
  return e;
}

EpochReport Trainer::run_epoch() {
  if (finished()) throw std::logic_error("Trainer::run_epoch: all epochs are done");
  io::Stopwatch watch;
  EpochReport report;
  report.lr = learning_rate(options_, epoch_);
  report.beta = soft_mip_beta(options_, epoch_);
  std::vector<int> order(static_cast<std::size_t>(data_.count()));
  std::iota(order.begin(), order.end(), 0);
  std::shuffle(order.begin(), order.end(), rng_);
  const std::size_t B = static_cast<std::size_t>(options_.views_per_step);
  for (std::size_t start = 0; start < order.size(); start += B) {
    const std::size_t n = std::min(B, order.size() - start);
    io::fault_point("train_step");
    const StepSums sums = train_step(std::span<const int>(order).subspan(start, n));
    report.loss += sums.loss;
    report.psnr += sums.psnr;
  }
  report.loss /= static_cast<double>(order.size());
  report.psnr /= static_cast<double>(order.size());
  ++epoch_;
  report.epoch = epoch_;
  if (epoch_ >= options_.densify_from && epoch_ <= options_.densify_until && epoch_ % options_.densify_every == 0) {
    const DensifyChange change = densify();
    report.split = change.split;
    report.cloned = change.cloned;
  }
  if (epoch_ % options_.prune_every == 0) report.pruned = prune();
  report.gaussians = gaussians();
  report.seconds = watch.elapsed();
  return report;
}

DensifyChange Trainer::densify() {
  const std::size_t K = params_.size() / kP;
  std::vector<std::size_t> candidates;
  std::vector<double> mean_grad(K, 0.0);
  for (std::size_t k = 0; k < K; ++k) {
    if (grad_count_[k] == 0) continue;
    mean_grad[k] = grad_accum_[k] / grad_count_[k];
    if (mean_grad[k] >= options_.densify_grad_threshold) candidates.push_back(k);
  }
  std::stable_sort(candidates.begin(), candidates.end(),
                   [&](std::size_t a, std::size_t b) { return mean_grad[a] > mean_grad[b]; });
  DensifyChange change;
  long long room = static_cast<long long>(options_.max_gaussians) - static_cast<long long>(K);
  const float log_split = static_cast<float>(std::log(options_.split_scale));
  for (std::size_t k : candidates) {
    if (room <= 0) break;
    std::array<float, kP> parent;
    std::copy_n(params_.begin() + static_cast<std::ptrdiff_t>(k * kP), kP, parent.begin());
    const gmf::GaussianParams g = gmf::from_array(parent);
    int axis = 0;
    for (int a = 1; a < 3; ++a) {
      if (g.log_scale[a] > g.log_scale[axis]) axis = a;
    }
    const double s_max = std::exp(static_cast<double>(g.log_scale[axis]));
    std::array<float, kP> twin = parent;
    if (s_max > options_.densify_scale_threshold) {
      // Eq. 17: μ ± split_offset s_max along the longest axis (column `axis` of R(q)), s × split_scale.
      const Eigen::Matrix3d R = gmf::rotation_matrix<double>(g);
      float* p = params_.data() + k * kP;
      for (int r = 0; r < 3; ++r) {
        const double step = options_.split_offset * s_max * R(r, axis);
        p[r] = static_cast<float>(parent[static_cast<std::size_t>(r)] + step);
        twin[static_cast<std::size_t>(r)] = static_cast<float>(parent[static_cast<std::size_t>(r)] - step);
      }
      for (std::size_t a = 3; a < 6; ++a) {
        p[a] = parent[a] + log_split;
        twin[a] = p[a];
      }
      // The parent became a new Gaussian: its moments restart like its twin's.
      std::fill_n(m_.begin() + static_cast<std::ptrdiff_t>(k * kP), kP, 0.0f);
      std::fill_n(v_.begin() + static_cast<std::ptrdiff_t>(k * kP), kP, 0.0f);
      ++change.split;
    } else {
      ++change.cloned;
    }
    io::fault_point("densify");  // some Gaussians split, the rest not yet
    params_.insert(params_.end(), twin.begin(), twin.end());
    m_.insert(m_.end(), kP, 0.0f);
    v_.insert(v_.end(), kP, 0.0f);
    --room;
  }
  resize_state(params_.size() / kP);
  return change;
}

int Trainer::prune() {
  const std::size_t K = params_.size() / kP;
  std::size_t kept = 0;
  for (std::size_t k = 0; k < K; ++k) {
    if (gmf::sigmoid(static_cast<double>(params_[k * kP + kP - 1])) < options_.prune_intensity) continue;
    if (kept != k) {
      const auto from = static_cast<std::ptrdiff_t>(k * kP), to = static_cast<std::ptrdiff_t>(kept * kP);
      std::copy_n(params_.begin() + from, kP, params_.begin() + to);
      std::copy_n(m_.begin() + from, kP, m_.begin() + to);
      std::copy_n(v_.begin() + from, kP, v_.begin() + to);
      grad_accum_[kept] = grad_accum_[k];
      grad_count_[kept] = grad_count_[k];
    }
    ++kept;
  }
  params_.resize(kept * kP);
  m_.resize(kept * kP);
  v_.resize(kept * kP);
  grad_accum_.resize(kept);
  grad_count_.resize(kept);
  return static_cast<int>(K - kept);
}

std::string Trainer::serialize_state() const {
  Writer w;
  w.put(kStateMagic);
  w.put<std::int32_t>(epoch_);
  w.put<std::int64_t>(step_);
  w.put<std::uint64_t>(params_.size() / kP);
  w.put<std::uint64_t>(fnv1a(params_.data(), params_.size() * sizeof(float)));
  w.put_array(std::span<const float>(m_));
  w.put_array(std::span<const float>(v_));
  w.put_array(std::span<const double>(grad_accum_));
  w.put_array(std::span<const std::uint32_t>(grad_count_));
  std::ostringstream rng;
  rng << rng_;
  w.put_string(rng.str());
  w.put_string(options_text(options_));
  return w.take();
}

void Trainer::restore_state(std::string_view bytes, std::vector<float> params, const std::string& source) {
  Reader r(bytes, source);
  const auto magic = r.get<std::array<char, 8>>();
  if (std::memcmp(magic.data(), kStateMagic, 8) != 0) r.fail("not a hisnegs training state file");
  const auto epoch = r.get<std::int32_t>();
  const auto step = r.get<std::int64_t>();
  const auto K = r.get<std::uint64_t>();
  const auto hash = r.get<std::uint64_t>();
  if (K * kP != params.size()) {
    r.fail("written for " + std::to_string(K) + " Gaussians, the checkpoint has " + std::to_string(params.size() / kP));
  }
  if (hash != fnv1a(params.data(), params.size() * sizeof(float))) {
    r.fail("the checkpoint's parameters are not the ones this state was saved with");
  }
  std::vector<float> m = r.get_array<float>(K * kP);
  std::vector<float> v = r.get_array<float>(K * kP);
  std::vector<double> accum = r.get_array<double>(K);
  std::vector<std::uint32_t> count = r.get_array<std::uint32_t>(K);
  std::istringstream rng_text(r.get_string());
  std::mt19937_64 rng;
  rng_text >> rng;
  if (!rng_text) r.fail("malformed random-number-generator state");
  const std::string saved = r.get_string();
  if (!r.done()) r.fail("trailing bytes");
  // Every option but `epochs` must match: a different schedule would not continue the run.
  std::istringstream a(saved), b(options_text(options_));
  for (std::string la, lb; std::getline(a, la) && std::getline(b, lb);) {
    if (la != lb && la.rfind("epochs=", 0) != 0) {
      r.fail("saved with train." + la + ", the current configuration has train." + lb);
    }
  }
  if (epoch < 0 || step < 0) r.fail("negative epoch or step");
  params_ = std::move(params);
  m_ = std::move(m);
  v_ = std::move(v);
  grad_accum_ = std::move(accum);
  grad_count_ = std::move(count);
  rng_ = rng;
  epoch_ = epoch;
  step_ = step;
}

std::filesystem::path checkpoint_ply_path(const std::filesystem::path& dir, int epoch) {
  return dir / ("epoch_" + epoch_tag(epoch) + ".ply");
}

std::filesystem::path checkpoint_state_path(const std::filesystem::path& dir, int epoch) {
  return dir / ("state_" + epoch_tag(epoch) + ".bin");
}

void save_training_checkpoint(const std::filesystem::path& dir, const Trainer& trainer,
                              const gmf::CheckpointMeta& meta) {
  const auto params = trainer.params();
  gmf::GaussianMixture mixture;
  mixture.reserve(static_cast<std::size_t>(trainer.gaussians()));
  for (std::size_t k = 0; k * kP < params.size(); ++k) {
    std::array<float, kP> values;
    std::copy_n(params.begin() + static_cast<std::ptrdiff_t>(k * kP), kP, values.begin());
    mixture.push_back(gmf::from_array(values));
  }
  gmf::CheckpointMeta m = meta;
  std::erase_if(m.extra, [](const auto& kv) { return kv.first == "train_epoch"; });
  m.extra.emplace_back("train_epoch", std::to_string(trainer.epoch()));
  // Order matters: a crash leaves `latest` naming the previous complete pair.
  gmf::save_checkpoint(checkpoint_ply_path(dir, trainer.epoch()), mixture, m);
  io::fault_point("checkpoint_write");  // the model is written, its state and `latest` are not yet
  const std::string state = trainer.serialize_state();
  io::write_file_atomic(checkpoint_state_path(dir, trainer.epoch()), state.data(), state.size());
  const std::string latest = epoch_tag(trainer.epoch()) + "\n";
  io::write_file_atomic(dir / "latest", latest.data(), latest.size());
}

int resume_training(const std::filesystem::path& dir, Trainer& trainer) {
  const std::filesystem::path latest = dir / "latest";
  if (!std::filesystem::exists(latest)) io::fail_input(latest, "no checkpoint to resume from (file missing)");
  io::remove_stale_temporaries(dir);  // a write the crash interrupted; `latest` never names one
  const std::string text = io::read_file(latest);
  int epoch = -1;
  char tail = 0;
  if (std::sscanf(text.c_str(), "%d%c", &epoch, &tail) < 1 || epoch < 0 || (tail != 0 && tail != '\n')) {
    io::fail_input(latest, "expected one epoch number, got \"" + io::printable(text, 40) + "\"");
  }
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(checkpoint_ply_path(dir, epoch));
  const auto flat = flat_params(checkpoint.mixture);
  std::vector<float> params(flat.begin(), flat.end());
  const std::filesystem::path state_path = checkpoint_state_path(dir, epoch);
  trainer.restore_state(io::read_file(state_path), std::move(params), state_path.string());
  if (trainer.epoch() != epoch) io::fail_input(state_path, "holds epoch " + std::to_string(trainer.epoch()));
  return epoch;
}

}  // namespace hisnegs::splat
