// SPDX-License-Identifier: Apache-2.0
// hisnegs._hisnegs: the pipeline library for Python (pybind11). The public names
// and their docstrings are hisnegs/__init__.py's, which turns keyword options into
// the config text that load_app_config_text validates as the CLI's --config does.
// Arrays are numpy views of the objects' own storage where the layout allows (a
// volume's voxels, a model's parameters); long calls release the GIL and call
// back into Python only for progress lines, where Ctrl-C is noticed.
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "apps/pipeline/app_config.hpp"
#include "apps/pipeline/export_model.hpp"
#include "apps/pipeline/file_info.hpp"
#include "apps/pipeline/fit_stage.hpp"
#include "apps/pipeline/optimizer_comparison.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/train_stage.hpp"
#include "gmf/block_index.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/compare.hpp"
#include "gmf/fit.hpp"
#include "gmf/objective.hpp"
#include "gmf/core/rasterize.hpp"
#include "gmf/round_solver.hpp"
#include "io/error.hpp"
#include "io/load_volume.hpp"
#include "io/memory_limit.hpp"
#include "splat/background_floor.hpp"
#include "splat/backend.hpp"
#include "splat/camera.hpp"
#include "splat/ground_truth.hpp"
#include "splat/metrics.hpp"
#include "splat/render_views.hpp"

namespace py = pybind11;

namespace hisnegs::python {
namespace {

using apps::AppConfig;
using FloatArray = py::array_t<float, py::array::c_style | py::array::forcecast>;
using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

// The options of a call: the built-in defaults overlaid with `config_text` (YAML of
// the sections given as keyword arguments), validated; errors name `origin`.
AppConfig config_of(const std::string& config_text, const std::string& origin) {
  return apps::load_app_config_text(config_text, origin);
}

// Progress lines to a Python callable (or nowhere), each one a chance for Ctrl-C:
// a pending KeyboardInterrupt is raised from the line that notices it.
apps::Progress python_progress(const std::optional<py::function>& callback) {
  apps::Progress p;
  p.line = [callback](std::string_view line) {
    py::gil_scoped_acquire gil;
    if (callback) (*callback)(std::string(line));
    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
  };
  return p;
}

// ---- volumes -------------------------------------------------------------------

struct Volume {
  io::LoadedVolume loaded;  // its volume.source names the file, or "numpy array"
};

py::array voxels_view(const std::shared_ptr<Volume>& v) {
  const io::Volume& vol = v->loaded.volume;
  const auto s = static_cast<py::ssize_t>(sizeof(float));
  return py::array_t<float>({vol.nz, vol.ny, vol.nx}, {s * vol.nx * vol.ny, s * vol.nx, s},
                            v->loaded.volume.voxels.data(), py::cast(v));
}

std::shared_ptr<Volume> load_volume(const std::filesystem::path& path, const std::string& config_text) {
  const AppConfig config = config_of(config_text, "hisnegs.load_volume() options");
  auto v = std::make_shared<Volume>();
  {
    py::gil_scoped_release release;
    v->loaded = io::load_volume(path, config.volume);
  }
  v->loaded.volume.source = path.string();  // as given, as `fit` records it (a BDV .xml, not its .h5)
  return v;
}

std::shared_ptr<Volume> volume_from_array(const py::array& array, const std::string& config_text) {
  const AppConfig config = config_of(config_text, "hisnegs.Volume.from_array() options");
  if (array.ndim() != 3) {
    throw io::InputError("hisnegs.Volume.from_array: an array of " + std::to_string(array.ndim()) +
                         " dimensions; expected 3 (z, y, x)");
  }
  const FloatArray values = FloatArray::ensure(array);
  if (!values) {  // say why: numpy's own error (a MemoryError for a huge array, a ValueError for objects)
    std::string why = "unknown reason";
    try {
      (void)py::module_::import("numpy").attr("ascontiguousarray")(array, "float32");
    } catch (py::error_already_set& e) {
      why = e.what();
    }
    throw io::InputError("hisnegs.Volume.from_array: the array of " + std::to_string(array.size()) + " values (" +
                         io::gib_text(4.0 * static_cast<double>(array.size())) +
                         " as float32) does not convert to float32: " + io::printable(why, 200));
  }
  io::Volume raw;
  raw.nz = static_cast<int>(values.shape(0));
  raw.ny = static_cast<int>(values.shape(1));
  raw.nx = static_cast<int>(values.shape(2));
  raw.voxels.assign(values.data(), values.data() + values.size());
  raw.source = "numpy array";
  auto v = std::make_shared<Volume>();
  {
    py::gil_scoped_release release;
    v->loaded = io::prepare_volume(std::move(raw), config.volume, "numpy array");
  }
  return v;
}

// ---- cameras -------------------------------------------------------------------

splat::CameraSet orbit_cameras(const std::string& kind, const std::string& config_text) {
  const AppConfig config = config_of(config_text, "hisnegs.Cameras.orbit() options");
  if (kind == "train") return splat::training_orbit(config.camera);
  if (kind == "eval") return splat::evaluation_orbit(config.camera);
  throw io::InputError("hisnegs.Cameras.orbit: kind '" + kind + "'; expected train | eval");
}

splat::CameraSet custom_cameras(const std::vector<double>& elevations, const std::vector<double>& azimuths,
                                const std::string& config_text) {
  const AppConfig config = config_of(config_text, "hisnegs.Cameras.custom() options");
  if (elevations.empty() || azimuths.empty()) {
    throw io::InputError("hisnegs.Cameras.custom: give at least one elevation and one azimuth");
  }
  return splat::custom_orbit(config.camera, elevations, azimuths);
}

// ---- models --------------------------------------------------------------------

struct Model {
  gmf::Checkpoint checkpoint;
};

// Model.params is a writable view: a call that renders, trains or writes a model
// refuses one holding NaN or Inf (ValueError naming the call and the first value).
void require_finite(const Model& m, const char* call) {
  const std::span<const float> params = gmf::flat_params(m.checkpoint.mixture);
  if (const std::string bad = gmf::describe_non_finite<float>(params, "value"); !bad.empty()) {
    throw io::InputError(std::string(call) + ": " + bad + " is not finite");
  }
}

py::array params_view(const std::shared_ptr<Model>& m) {
  gmf::GaussianMixture& g = m->checkpoint.mixture;
  const auto s = static_cast<py::ssize_t>(sizeof(float));
  return py::array_t<float>({static_cast<py::ssize_t>(g.size()), static_cast<py::ssize_t>(gmf::kGaussianParamCount)},
                            {s * static_cast<py::ssize_t>(gmf::kGaussianParamCount), s},
                            reinterpret_cast<float*>(g.data()), py::cast(m));
}

// A C-ordered array of `shape` that owns `values` (moved, not copied).
py::array owning_array(std::vector<float>&& values, std::vector<py::ssize_t> shape) {
  auto* owned = new std::vector<float>(std::move(values));
  py::capsule owner(owned, [](void* p) { delete static_cast<std::vector<float>*>(p); });
  return py::array_t<float>(std::move(shape), owned->data(), owner);
}

py::array stack_array(splat::MipStack&& stack) {
  return owning_array(std::move(stack.pixels), {stack.views, stack.height, stack.width});
}

// The back end a `backend` argument ("auto" | "cpu" | "cuda") asks for, as --backend.
splat::Backend backend_of(const std::string& backend) {
  return splat::resolve_backend(splat::parse_backend_request(backend, "backend"));
}

py::array render_model(const Model& m, const splat::CameraSet& cameras, const std::string& config_text,
                       const std::string& backend) {
  require_finite(m, "hisnegs.Model.render");
  const AppConfig config = config_of(config_text, "hisnegs.Model.render() options");
  const splat::Backend b = backend_of(backend);
  splat::MipStack stack;
  {
    py::gil_scoped_release release;
    const auto params = splat::flat_params(m.checkpoint.mixture);
    const splat::SplatSettings settings = splat::SplatSettings::from(config.splat);
    const splat::BackgroundFloors floors = splat::floors_of(m.checkpoint.meta, "the model", config.splat.background);
    auto renderer = splat::make_splat_renderer(b);
    stack = splat::render_views(*renderer, params, cameras, settings, {}, floors).stack;
  }
  return stack_array(std::move(stack));
}

py::array rasterize_model(const Model& m, const std::optional<std::vector<int>>& shape_zyx) {
  const gmf::CheckpointMeta& meta = m.checkpoint.meta;
  std::optional<io::WorldFrame> frame = gmf::model_frame(meta);
  if (shape_zyx) {
    if (shape_zyx->size() != 3 || *std::min_element(shape_zyx->begin(), shape_zyx->end()) < 1) {
      throw io::InputError("hisnegs.Model.rasterize: shape must be 3 positive sizes (z, y, x)");
    }
    const Eigen::Vector3d aspect = meta.aspect ? Eigen::Vector3d((*meta.aspect)[0], (*meta.aspect)[1], (*meta.aspect)[2])
                                               : Eigen::Vector3d(1, 1, 1);
    frame.emplace((*shape_zyx)[2], (*shape_zyx)[1], (*shape_zyx)[0], aspect);
  }
  if (!frame) {
    throw io::InputError("hisnegs.Model.rasterize: the model records no volume shape; give shape=(z, y, x)");
  }
  const gmf::RasterizeOptions options = gmf::RasterizeOptions::of(gmf::model_of(meta));
  std::vector<float> voxels;
  {
    py::gil_scoped_release release;
    voxels = gmf::rasterize_mixture(m.checkpoint.mixture, *frame, options);
  }
  const Eigen::Vector3i& n = frame->shape();
  return owning_array(std::move(voxels), {n.z(), n.y(), n.x()});
}

std::shared_ptr<Model> fit(const Volume& volume, const std::string& config_text,
                           const std::optional<py::function>& progress) {
  const AppConfig config = config_of(config_text, "hisnegs.fit() options");
  auto m = std::make_shared<Model>();
  const apps::Progress sink = python_progress(progress);
  {
    py::gil_scoped_release release;
    m->checkpoint =
        apps::fit_loaded(volume.loaded, volume.loaded.volume.source, apps::FitConfig(config), sink).checkpoint;
  }
  return m;
}

// Stage 2 on views in memory: `images` (V, H, W) of `cameras`' views, with the
// train section's schedule (on the CPU back end the CPU schedule when none is
// configured, as `train` does) and train.keep_better_init.
std::shared_ptr<Model> train(const Model& init, const FloatArray& images, const splat::CameraSet& cameras,
                             const std::string& config_text, const std::string& backend,
                             const std::optional<py::function>& progress) {
  require_finite(init, "hisnegs.train");
  AppConfig config = config_of(config_text, "hisnegs.train() options");
  const splat::Backend b = backend_of(backend);
  const splat::Intrinsics& K = cameras.intrinsics;
  if (images.ndim() != 3 || images.shape(0) != static_cast<py::ssize_t>(cameras.views.size()) ||
      images.shape(1) != K.height || images.shape(2) != K.width) {
    throw io::InputError("hisnegs.train: the images must be (views, height, width) = (" +
                         std::to_string(cameras.views.size()) + ", " + std::to_string(K.height) + ", " +
                         std::to_string(K.width) + ") for these cameras");
  }
  const apps::Progress sink = python_progress(progress);
  auto out = std::make_shared<Model>();
  {
    py::gil_scoped_release release;
    apps::choose_train_schedule(config, b, sink);
    splat::TrainingData data{K, cameras.views, std::vector<float>(images.data(), images.data() + images.size())};
    splat::Trainer trainer = apps::make_trainer(init.checkpoint, "the model", std::move(data),
                                                apps::TrainConfig(config), b, sink);
    while (!trainer.finished()) {
      const splat::EpochReport r = trainer.run_epoch();
      sink.say("train: epoch %d/%d: loss %.6g, PSNR %.2f dB, K %d, beta %.4g", r.epoch, config.train.epochs, r.loss,
               r.psnr, r.gaussians, r.beta);
    }
    const auto initial = splat::flat_params(init.checkpoint.mixture);
    const double before = trainer.evaluate(initial, config.train.beta_end).psnr;
    const double after = trainer.evaluate(trainer.params(), config.train.beta_end).psnr;
    const bool keep = config.train.keep_better_init && after < before;
    sink.say("train: the %zu views at beta %g: initial model %.2f dB, trained %.2f dB%s", cameras.views.size(),
             config.train.beta_end, before, after, keep ? ": kept the initial model (train.keep_better_init)" : "");
    out->checkpoint.meta = init.checkpoint.meta;
    if (keep) {
      out->checkpoint.mixture = init.checkpoint.mixture;
    } else {
      out->checkpoint.mixture = gmf::mixture_from_flat(trainer.params());
      out->checkpoint.meta.extra.emplace_back("train_epoch", std::to_string(trainer.epoch()));
    }
  }
  return out;
}

// hisnegs.info: `hisnegs info`'s description of a file.
py::dict file_info(const std::filesystem::path& path, const std::string& config_text) {
  const AppConfig config = config_of(config_text, "hisnegs.info() options");
  apps::FileInfo info;
  {
    py::gil_scoped_release release;
    info = apps::describe_file(path, config.volume);
  }
  py::list rows;
  for (const apps::FileInfo::Line& line : info.lines) rows.append(py::make_tuple(line.key, line.text));
  py::dict r;
  r["kind"] = info.kind;
  r["rows"] = rows;
  r["text"] = info.text();
  return r;
}

// ---- exports (apps/pipeline/export_model.hpp, as `hisnegs export`) ---------------------

py::dict export_vdb(const Model& m, const std::filesystem::path& out, std::optional<double> voxel_size,
                    const std::string& match_volume, double cutoff, double tail, bool points, bool untruncated_sum,
                    const std::string& config_text) {
  require_finite(m, "hisnegs.export_vdb");
  const AppConfig config = config_of(config_text, "hisnegs.export_vdb() options");
  apps::VdbExportRequest request;
  request.voxel_size = voxel_size;
  request.match_volume = match_volume;
  request.volume = config.volume;
  request.options.cutoff = cutoff;
  request.options.tail = tail;
  request.options.points = points;
  request.options.untruncated_sum = untruncated_sum;
  request.options.support = config.gmf.mahalanobis_cutoff;
  request.instead = "voxel_size=V or match_volume=PATH";
  apps::VdbExportDone done;
  {
    py::gil_scoped_release release;
    done = apps::export_model_vdb(m.checkpoint, "the model", out, request);
  }
  py::dict r;
  r["active_voxels"] = done.report.active_voxels;
  r["leaves"] = done.report.leaf_count;
  r["gaussians"] = done.report.gaussians;
  r["file_bytes"] = done.report.file_bytes;
  r["lattice"] = done.lattice;
  r["function"] = done.function;
  return r;
}

py::dict export_volume(const Model& m, const std::filesystem::path& out, const std::string& match_volume, double tail,
                       bool untruncated_sum, const std::string& config_text) {
  require_finite(m, "hisnegs.export_volume");
  const AppConfig config = config_of(config_text, "hisnegs.export_volume() options");
  apps::VolumeExportRequest request;
  request.match_volume = match_volume;
  request.volume = config.volume;
  request.tail = tail;
  request.untruncated_sum = untruncated_sum;
  request.support = config.gmf.mahalanobis_cutoff;
  request.instead = "match_volume=PATH";
  apps::VolumeExportDone done;
  {
    py::gil_scoped_release release;
    done = apps::export_model_volume(m.checkpoint, "the model", out, request);
  }
  const Eigen::Vector3i& n = done.frame.shape();
  py::dict r;
  r["shape"] = py::make_tuple(n.z(), n.y(), n.x());
  r["psnr"] = done.psnr ? py::cast(*done.psnr) : py::none();
  r["function"] = done.function;
  return r;
}

py::dict export_compact(const Model& m, const std::filesystem::path& out, int position_bits, int scale_bits,
                        int rotation_bits, int intensity_bits, int level) {
  require_finite(m, "hisnegs.export_compact");
  gmf::CompactOptions options;
  options.position_bits = position_bits;
  options.scale_bits = scale_bits;
  options.rotation_bits = rotation_bits;
  options.intensity_bits = intensity_bits;
  options.zstd_level = level;
  gmf::CompactHeader h;
  {
    py::gil_scoped_release release;
    h = apps::export_model_compact(m.checkpoint, out, options);
  }
  const gmf::CompactBounds b = gmf::compact_bounds(h);
  py::dict r;
  r["gaussians"] = h.count;
  r["file_bytes"] = h.file_bytes;
  r["bytes_per_gaussian"] = h.count > 0 ? static_cast<double>(h.file_bytes) / static_cast<double>(h.count) : 0.0;
  r["max_error"] = py::dict(py::arg("position") = *std::max_element(b.position.begin(), b.position.end()),
                            py::arg("log_scale") = *std::max_element(b.log_scale.begin(), b.log_scale.end()),
                            py::arg("quaternion") = b.rotation, py::arg("intensity") = b.intensity);
  return r;
}

py::dict export_html(const Model& m, const std::filesystem::path& out, const std::optional<splat::CameraSet>& cameras,
                     bool float32, const std::string& config_text) {
  require_finite(m, "hisnegs.export_html");
  const AppConfig config = config_of(config_text, "hisnegs.export_html() options");
  const splat::CameraSet views = cameras ? *cameras : splat::evaluation_orbit(config.camera);
  apps::HtmlExportDone done;
  {
    py::gil_scoped_release release;
    done = apps::export_model_html(m.checkpoint, "the model", out, views, config.splat, float32);
  }
  py::dict r;
  r["page_bytes"] = done.page_bytes;
  r["model_bytes"] = done.model_block_bytes;
  r["views"] = views.views.size();
  return r;
}

// ---- ground truth and metrics ----------------------------------------------------

py::array ground_truth(const Volume& volume, const splat::CameraSet& cameras, const std::string& config_text,
                       const std::string& backend) {
  const AppConfig config = config_of(config_text, "hisnegs.ground_truth() options");
  const splat::Backend b = backend_of(backend);
  splat::MipStack stack;
  {
    py::gil_scoped_release release;
    stack = splat::render_ground_truth(volume.loaded.volume, volume.loaded.frame, cameras, config.raymarch, b);
  }
  return stack_array(std::move(stack));
}

py::dict metrics(const FloatArray& render, const FloatArray& target) {
  if (render.ndim() != target.ndim() || !std::equal(render.shape(), render.shape() + render.ndim(), target.shape())) {
    throw io::InputError("hisnegs.metrics: the arrays' shapes differ");
  }
  if (render.ndim() != 2 && render.ndim() != 3) {
    throw io::InputError("hisnegs.metrics: images (H, W) or stacks of them (V, H, W) expected");
  }
  const int views = render.ndim() == 3 ? static_cast<int>(render.shape(0)) : 1;
  const int h = static_cast<int>(render.shape(render.ndim() - 2)), w = static_cast<int>(render.shape(render.ndim() - 1));
  const std::size_t n = static_cast<std::size_t>(w) * h;
  std::vector<double> psnr(static_cast<std::size_t>(views)), ssim(psnr.size()), mae(psnr.size());
  {
    py::gil_scoped_release release;
    for (int i = 0; i < views; ++i) {
      const splat::ViewMetrics m = splat::image_metrics({render.data() + n * i, n}, {target.data() + n * i, n}, w, h);
      psnr[static_cast<std::size_t>(i)] = m.psnr;
      ssim[static_cast<std::size_t>(i)] = m.ssim;
      mae[static_cast<std::size_t>(i)] = m.mae;
    }
  }
  py::dict out;
  const auto mean = [](const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x;
    return s / static_cast<double>(v.size());
  };
  out["psnr"] = mean(psnr);
  out["ssim"] = mean(ssim);
  out["mae"] = mean(mae);
  out["psnr_per_view"] = py::array_t<double>(static_cast<py::ssize_t>(psnr.size()), psnr.data());
  out["ssim_per_view"] = py::array_t<double>(static_cast<py::ssize_t>(ssim.size()), ssim.data());
  out["mae_per_view"] = py::array_t<double>(static_cast<py::ssize_t>(mae.size()), mae.data());
  return out;
}

// ---- the stage-1 objective --------------------------------------------------------

// value, gradient and value_and_gradient of a flat float64 x of size() values over
// Derived's `double evaluate(const double* x, double* gradient)`, and the check of
// such an x (io::InputError naming Derived::kName): shared by Objective and
// RoundProblem.
template <class Derived>
class GradientCalls {
 public:
  double value(const DoubleArray& x) { return self().evaluate(checked(x), nullptr); }
  py::array_t<double> gradient(const DoubleArray& x) {
    py::array_t<double> g(static_cast<py::ssize_t>(self().size()));
    self().evaluate(checked(x), g.mutable_data());
    return g;
  }
  py::tuple value_and_gradient(const DoubleArray& x) {
    py::array_t<double> g(static_cast<py::ssize_t>(self().size()));
    const double v = self().evaluate(checked(x), g.mutable_data());
    return py::make_tuple(v, g);
  }

 protected:
  // x's values, once it is a flat array of size() finite values whose quaternions
  // are not zero (scipy's line searches try such points; they crashed the index).
  const double* checked(const DoubleArray& x) const {
    const std::size_t n = static_cast<const Derived&>(*this).size();
    if (x.ndim() != 1 || static_cast<std::size_t>(x.size()) != n) {
      throw io::InputError(std::string(Derived::kName) + ": x must be a flat array of 11 K = " + std::to_string(n) +
                           " values (got " + std::to_string(x.size()) + ")");
    }
    const double* p = x.data();
    constexpr std::size_t kP = gmf::kGaussianParamCount;
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(p[i])) {
        throw io::InputError(std::string(Derived::kName) + ": x[" + std::to_string(i) + "] (Gaussian " +
                             std::to_string(i / kP) + ", parameter " + std::to_string(i % kP) + ") is " +
                             std::to_string(p[i]) + ", not a finite value");
      }
    }
    for (std::size_t k = 0; k < n / kP; ++k) {
      const double* q = p + kP * k + gmf::kRotW;
      if (q[0] == 0.0 && q[1] == 0.0 && q[2] == 0.0 && q[3] == 0.0) {
        throw io::InputError(std::string(Derived::kName) + ": Gaussian " + std::to_string(k) +
                             "'s quaternion (x[" + std::to_string(kP * k + gmf::kRotW) + "..]) is zero");
      }
    }
    return p;
  }

 private:
  Derived& self() { return static_cast<Derived&>(*this); }
};

// The fit's least-squares problem on a volume: its samples and weights (the sparse
// grid with gmf.background_fraction, at the voxel centres), the model's mixture as
// the size of x, and the mixture model (aggregation, β, cutoff). The block index is
// rebuilt for each new x, so x may move anywhere.
class Objective : public GradientCalls<Objective> {
 public:
  static constexpr const char* kName = "hisnegs.Objective";
  Objective(const Volume& volume, const Model& model, const std::string& config_text, const std::string& aggregation,
            double beta) {
    const AppConfig config = config_of(config_text, "hisnegs.Objective() options");
    gmf::GmfOptions gmf = config.gmf;
    if (aggregation != "softmax" && aggregation != "sum" && aggregation != "max") {
      throw io::InputError("hisnegs.Objective: aggregation '" + aggregation + "'; expected softmax | sum | max");
    }
    if (!(beta > 0) || !std::isfinite(beta)) throw io::InputError("hisnegs.Objective: beta must be > 0");
    model_.aggregation = aggregation == "sum"   ? gmf::Aggregation::kSum
                         : aggregation == "max" ? gmf::Aggregation::kMax
                                                : gmf::Aggregation::kSoftmax;
    model_.beta = beta;
    model_.cutoff = gmf.mahalanobis_cutoff;
    gaussians_ = model.checkpoint.mixture.size();
    if (gaussians_ == 0) throw io::InputError("hisnegs.Objective: the model has no Gaussians");
    const std::span<const float> params = gmf::flat_params(model.checkpoint.mixture);
    if (const std::string bad = gmf::describe_non_finite<float>(params, "value"); !bad.empty()) {
      throw io::InputError("hisnegs.Objective: the model's " + bad + " is not finite");
    }
    frame_ = volume.loaded.frame;
    py::gil_scoped_release release;
    io::SparseGridOptions sparse = config.sparse_grid;
    sparse.background_fraction = gmf.background_fraction;
    const io::SparseGrid grid = io::build_sparse_grid(volume.loaded.volume, frame_.aspect(), sparse);
    samples_ = gmf::fit_samples(grid, gmf);
  }
  [[nodiscard]] std::size_t size() const { return gmf::kGaussianParamCount * gaussians_; }
  [[nodiscard]] std::size_t samples() const { return samples_.size(); }

  py::array_t<double> residuals(const DoubleArray& x) {
    const gmf::SampleResiduals r = sample_residuals(x, false);
    return py::array_t<double>(static_cast<py::ssize_t>(r.residuals.size()), r.residuals.data());
  }
  // (values, column indices, row starts) of the Jacobian's CSR form.
  py::tuple jacobian(const DoubleArray& x) {
    const gmf::SampleResiduals r = sample_residuals(x, true);
    return py::make_tuple(py::array_t<double>(static_cast<py::ssize_t>(r.values.size()), r.values.data()),
                          py::array_t<std::int64_t>(static_cast<py::ssize_t>(r.columns.size()), r.columns.data()),
                          py::array_t<std::int64_t>(static_cast<py::ssize_t>(r.row_begin.size()), r.row_begin.data()));
  }
  // The loss at p (11 K values) and, when not null, its gradient.
  double evaluate(const double* p, double* gradient) {
    py::gil_scoped_release release;
    const gmf::BlockIndex index = index_at(p);
    const gmf::FitObjective objective(samples_, index, gaussians_, model_);
    return objective.evaluate(p, gradient);
  }

 private:
  // Which Gaussians may reach which sample blocks at x (rebuilt for every x).
  [[nodiscard]] gmf::BlockIndex index_at(const double* p) const {
    const std::vector<float> rounded(p, p + size());
    return gmf::build_block_index(gmf::mixture_from_flat(rounded), samples_, frame_, model_.cutoff);
  }
  gmf::SampleResiduals sample_residuals(const DoubleArray& x, bool with_jacobian) {
    const double* p = checked(x);
    py::gil_scoped_release release;
    return gmf::sample_residuals(samples_, index_at(p), model_, p, with_jacobian);
  }

  gmf::MixtureModel model_;
  std::size_t gaussians_ = 0;
  io::WorldFrame frame_;
  gmf::SampleSet samples_;
};

// ---- bring your own optimizer ----------------------------------------------------

// Raised by RoundProblem.iterate when the round must end (hisnegs.StopRound).
struct StopRound : std::runtime_error {
  StopRound() : std::runtime_error("the round's time is spent or the loss reached the target") {}
};

// A Python exception raised inside a C++ call that records failures and goes on
// (the comparison): kept here, passed up as io::Interrupted, raised again at the
// binding's boundary (rethrow_pending). Guarded by the GIL.
std::exception_ptr& pending_python_error() {
  static std::exception_ptr pending;
  return pending;
}

[[noreturn]] void defer_python_error() {
  pending_python_error() = std::current_exception();
  throw io::Interrupted("a Python exception stopped the call");
}

void rethrow_pending() {
  std::exception_ptr e = std::exchange(pending_python_error(), nullptr);
  if (e) std::rethrow_exception(e);
}

// Progress lines for calls that record failures: a Python exception (Ctrl-C) is deferred.
apps::Progress deferring_progress(const std::optional<py::function>& callback) {
  apps::Progress p;
  p.line = [callback](std::string_view line) {
    py::gil_scoped_acquire gil;
    try {
      if (callback) (*callback)(std::string(line));
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    } catch (const py::error_already_set&) {
      defer_python_error();
    }
  };
  return p;
}

// hisnegs.RoundProblem: one round of the stage-1 fit as a Python optimizer sees it
// (gmf::RoundSolverProblem). Valid only during the optimizer's call.
class RoundProblem : public GradientCalls<RoundProblem> {
 public:
  static constexpr const char* kName = "hisnegs.RoundProblem";
  explicit RoundProblem(const gmf::RoundSolverProblem& p)
      : p_(&p), last_x_(p.x.begin(), p.x.end()), iterate_(p.x.begin(), p.x.end()) {}

  [[nodiscard]] std::size_t size() const { return problem().x.size(); }
  py::array_t<double> x() const { return copy_of(problem().x); }
  py::array_t<double> lower() const { return copy_of(problem().lower); }
  py::array_t<double> upper() const { return copy_of(problem().upper); }
  // scipy's bounds: (lower, upper) pairs, None where unbounded.
  py::list bounds() const {
    const auto& p = problem();
    py::list out;
    for (std::size_t i = 0; i < p.x.size(); ++i) {
      out.append(py::make_tuple(std::isfinite(p.lower[i]) ? py::cast(p.lower[i]) : py::none(),
                                std::isfinite(p.upper[i]) ? py::cast(p.upper[i]) : py::none()));
    }
    return out;
  }
  [[nodiscard]] int max_iterations() const { return problem().max_iterations; }
  [[nodiscard]] double seconds_left() const { return problem().seconds_left; }
  [[nodiscard]] int iterations() const { return iterations_; }

  // The round's loss at p (size() values) and, when not null, its gradient; p
  // becomes the last point evaluated (iterate() logs it without evaluating again).
  double evaluate(const double* p, double* gradient) {
    const gmf::FitObjective& objective = problem().objective;
    double loss = 0;
    {
      py::gil_scoped_release release;
      loss = objective.evaluate(p, gradient);
    }
    std::copy(p, p + size(), last_x_.begin());
    last_loss_ = loss;
    has_last_ = true;
    return loss;
  }
  // One iteration ends at x: its loss is logged (the last evaluation's when it was
  // at x, else a new one) and x becomes the round's result so far. Raises
  // StopRound when the round must end.
  void iterate(const DoubleArray& x) {
    const double* p = checked(x);
    const bool known = has_last_ && std::memcmp(p, last_x_.data(), size() * sizeof(double)) == 0;
    const double loss = known ? last_loss_ : evaluate(p, nullptr);
    std::copy(p, p + size(), iterate_.begin());
    log(loss);
  }
  // The round's start, logged as every built-in optimizer logs it (iteration 0).
  void start() { log(evaluate(problem().x.data(), nullptr)); }
  // Where the round ends: `result` (the optimizer's return value) or, for None or a
  // StopRound, the last iterate.
  void finish(const py::object& result) {
    const auto& p = problem();
    if (!result.is_none()) {
      const DoubleArray r = DoubleArray::ensure(result);
      if (!r || r.ndim() != 1 || static_cast<std::size_t>(r.size()) != size()) {
        throw io::InputError("hisnegs.compare_optimizers: an optimizer returned something other than a flat array "
                             "of 11 K = " + std::to_string(size()) + " floats (or None)");
      }
      std::copy(r.data(), r.data() + size(), p.x.begin());
    } else {
      std::copy(iterate_.begin(), iterate_.end(), p.x.begin());
    }
  }
  void close() { p_ = nullptr; }

 private:
  const gmf::RoundSolverProblem& problem() const {
    if (p_ == nullptr) throw io::InputError("hisnegs.RoundProblem: used after its round ended");
    return *p_;
  }
  static py::array_t<double> copy_of(std::span<const double> v) {
    return py::array_t<double>(static_cast<py::ssize_t>(v.size()), v.data());
  }
  void log(double loss) {
    ++iterations_;
    const bool stop = problem().log(loss);
    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    if (stop) throw StopRound();
  }

  const gmf::RoundSolverProblem* p_;
  std::vector<double> last_x_, iterate_;
  double last_loss_ = 0;
  bool has_last_ = false;
  int iterations_ = 0;
};

// A Python callable as a round solver: called once per round with a RoundProblem.
gmf::NamedSolver python_solver(const std::string& name, const py::function& callable) {
  gmf::NamedSolver solver;
  solver.name = name;
  solver.description = "a Python callable";
  solver.solve = [name, callable](const gmf::RoundSolverProblem& p) {
    py::gil_scoped_acquire gil;
    auto problem = std::make_shared<RoundProblem>(p);
    gmf::RoundSolverOutcome out;
    try {
      problem->start();
      problem->finish(callable(problem));
      out.message = name + ": returned";
    } catch (const StopRound&) {
      problem->finish(py::none());
      out.message = name + ": stopped for time or at the target";
    } catch (py::error_already_set& e) {
      if (!e.matches(py::module_::import("hisnegs._hisnegs").attr("StopRound"))) {
        problem->close();
        defer_python_error();  // the optimizer's own error (or Ctrl-C): raised again by compare_optimizers
      }
      problem->finish(py::none());
      out.message = name + ": stopped for time or at the target";
    }
    out.iterations = problem->iterations();
    problem->close();
    return out;
  };
  return solver;
}

py::dict compare_optimizers(const Volume& volume, const std::vector<std::string>& builtins, const py::dict& custom,
                            const std::string& config_text, double budget_s, int adam_steps, bool stop_at_target,
                            const std::vector<std::string>& continuation, const std::string& output,
                            const std::optional<py::function>& progress) {
  const AppConfig config = config_of(config_text, "hisnegs.compare_optimizers() options");
  gmf::CompareOptions options;
  options.time_budget_s = budget_s;
  options.adam_steps = adam_steps;
  options.stop_at_target = stop_at_target;
  options.optimizers.clear();
  gmf::add_optimizers(options, builtins, "hisnegs.compare_optimizers builtins");
  options.continuation = gmf::builtin_optimizers(continuation, "hisnegs.compare_optimizers continuation");
  for (const auto& [key, value] : custom) {
    const std::string name = py::str(key);
    if (!PyCallable_Check(value.ptr())) {
      throw io::InputError("hisnegs.compare_optimizers: optimizers['" + name + "'] is not callable");
    }
    options.custom.push_back(python_solver(name, py::reinterpret_borrow<py::function>(value)));
  }
  options.validate();
  const apps::Progress sink = deferring_progress(progress);
  gmf::Comparison c;
  try {
    py::gil_scoped_release release;
    const apps::FitConfig fit_config(config);
    const apps::FitSetup setup =
        apps::prepare_fit(volume.loaded, volume.loaded.volume.source, fit_config, "compare", sink);
    c = apps::compare_prepared(setup, volume.loaded.volume.source, fit_config, options, output, sink);
  } catch (const io::Interrupted&) {
    rethrow_pending();
    throw;
  }
  py::list runs;
  for (const gmf::OptimizerRun& run : c.runs) {
    py::dict r;
    r["name"] = run.name;
    r["seconds_to_target"] = run.seconds_to_target >= 0 ? py::cast(run.seconds_to_target) : py::none();
    r["final_loss"] = run.final_loss;
    r["final_psnr_3d"] = run.failure.empty() ? py::cast(run.result.final_psnr_3d) : py::none();
    r["iterations"] = run.iterations;
    r["seconds"] = run.result.seconds;
    r["gaussians"] = run.gaussians;
    r["stop_reason"] = run.result.stop_reason;
    r["continuation"] = run.continuation;
    r["failure"] = run.failure;
    std::vector<double> seconds, loss;
    std::vector<int> iteration;
    for (const gmf::FitIteration& it : run.result.log) {
      if (it.psnr_3d >= 0) continue;  // the final measurement line repeats the last loss
      seconds.push_back(it.seconds);
      loss.push_back(it.loss);
      iteration.push_back(it.iteration);
    }
    py::dict curve;
    curve["seconds"] = py::array_t<double>(static_cast<py::ssize_t>(seconds.size()), seconds.data());
    curve["loss"] = py::array_t<double>(static_cast<py::ssize_t>(loss.size()), loss.data());
    curve["iteration"] = py::array_t<int>(static_cast<py::ssize_t>(iteration.size()), iteration.data());
    r["curve"] = curve;
    runs.append(r);
  }
  py::dict out;
  out["target_loss"] = c.target_loss > 0 ? py::cast(c.target_loss) : py::none();
  out["adam_steps_done"] = c.adam_steps_done;
  out["runs"] = runs;
  return out;
}

}  // namespace
}  // namespace hisnegs::python

namespace pybind11::detail {

// An object made with T.__new__ whose __init__ never ran holds no value: pybind11
// would hand uninitialised memory to the call. Such an argument (self included) is
// refused with TypeError instead.
template <class T>
struct initialised_caster : type_caster_base<T> {
  bool load(handle src, bool convert) {
    if (src && isinstance<T>(src)) {
      auto* inst = reinterpret_cast<instance*>(src.ptr());
      if (!inst->get_value_and_holder(get_type_info(typeid(T))).holder_constructed()) {
        const std::string name = str(src.get_type().attr("__name__"));
        throw type_error("hisnegs." + name + " made with " + name +
                         ".__new__ and never initialised: make one with its constructor or loader");
      }
    }
    return type_caster_base<T>::load(src, convert);
  }
};
template <>
struct type_caster<hisnegs::python::Volume> : initialised_caster<hisnegs::python::Volume> {};
template <>
struct type_caster<hisnegs::python::Model> : initialised_caster<hisnegs::python::Model> {};
template <>
struct type_caster<hisnegs::python::RoundProblem> : initialised_caster<hisnegs::python::RoundProblem> {};
template <>
struct type_caster<hisnegs::python::Objective> : initialised_caster<hisnegs::python::Objective> {};
template <>
struct type_caster<hisnegs::splat::CameraSet> : initialised_caster<hisnegs::splat::CameraSet> {};

}  // namespace pybind11::detail

PYBIND11_MODULE(_hisnegs, m) {
  using namespace hisnegs;
  using namespace hisnegs::python;
  m.doc() = "hisnegs' C++ core; use the hisnegs package (its __init__ documents every name)";

  py::register_exception<io::InputError>(m, "InputError", PyExc_ValueError);
  py::register_exception<io::WriteError>(m, "WriteError", PyExc_OSError);

  py::class_<Volume, std::shared_ptr<Volume>>(m, "Volume")
      .def_property_readonly("array", &voxels_view)
      .def_property_readonly("shape",
                             [](const Volume& v) {
                               const io::Volume& vol = v.loaded.volume;
                               return py::make_tuple(vol.nz, vol.ny, vol.nx);
                             })
      .def_property_readonly("spacing_um",
                             [](const Volume& v) {
                               const auto& s = v.loaded.volume.spacing.um;
                               return py::make_tuple(s[0], s[1], s[2]);
                             })
      .def_property_readonly("aspect",
                             [](const Volume& v) {
                               const Eigen::Vector3d& a = v.loaded.frame.aspect();
                               return py::make_tuple(a.x(), a.y(), a.z());
                             })
      .def_property_readonly("normalization",
                             [](const Volume& v) { return v.loaded.volume.normalization.describe(); })
      .def_property_readonly("source", [](const Volume& v) { return v.loaded.volume.source; });
  m.def("_load_volume", &load_volume);
  m.def("_volume_from_array", &volume_from_array);

  py::class_<splat::CameraSet>(m, "Cameras")
      .def_static("load", [](const std::filesystem::path& p) { return splat::read_cameras_json(p); })
      .def("save", [](const splat::CameraSet& c, const std::filesystem::path& p) { splat::write_cameras_json(p, c); })
      .def("__len__", [](const splat::CameraSet& c) { return c.views.size(); })
      .def_property_readonly("width", [](const splat::CameraSet& c) { return c.intrinsics.width; })
      .def_property_readonly("height", [](const splat::CameraSet& c) { return c.intrinsics.height; })
      .def_property_readonly("names", [](const splat::CameraSet& c) {
        std::vector<std::string> names;
        for (const splat::CameraView& v : c.views) names.push_back(v.name);
        return names;
      });
  m.def("_orbit_cameras", &orbit_cameras);
  m.def("_custom_cameras", &custom_cameras);

  py::class_<Model, std::shared_ptr<Model>>(m, "Model")
      .def_static("load",
                  [](const std::filesystem::path& p) {
                    auto model = std::make_shared<Model>();
                    model->checkpoint = gmf::load_checkpoint(p);
                    return model;
                  })
      .def("save",
           [](const Model& model, const std::filesystem::path& p) {
             require_finite(model, "hisnegs.Model.save");
             // .hgs: the compact checkpoint with export compact's defaults; anything else: the .ply
             py::gil_scoped_release release;
             if (p.extension() == ".hgs") {
               (void)apps::export_model_compact(model.checkpoint, p, gmf::CompactOptions{});
             } else {
               gmf::save_checkpoint(p, model.checkpoint.mixture, model.checkpoint.meta);
             }
           })
      .def("__len__", [](const Model& model) { return model.checkpoint.mixture.size(); })
      .def_property_readonly("params", &params_view)
      .def_property_readonly("aggregation",
                             [](const Model& model) {
                               return std::string(gmf::describe_aggregation(model.checkpoint.meta.aggregation));
                             })
      .def_property_readonly("beta", [](const Model& model) { return model.checkpoint.meta.beta; })
      .def("_render", &render_model)
      .def("_rasterize", &rasterize_model);
  m.def("_fit", &fit);
  m.def("_info", &file_info);
  m.def("_export_vdb", &export_vdb);
  m.def("_export_volume", &export_volume);
  m.def("_export_compact", &export_compact);
  m.def("_export_html", &export_html);
  m.def("_train", &train);
  m.def("_ground_truth", &ground_truth);
  m.def("metrics", &metrics);

  py::register_exception<StopRound>(m, "StopRound");
  py::class_<RoundProblem, std::shared_ptr<RoundProblem>>(m, "RoundProblem")
      .def_property_readonly("size", &RoundProblem::size)
      .def_property_readonly("x", &RoundProblem::x)
      .def_property_readonly("lower", &RoundProblem::lower)
      .def_property_readonly("upper", &RoundProblem::upper)
      .def_property_readonly("bounds", &RoundProblem::bounds)
      .def_property_readonly("max_iterations", &RoundProblem::max_iterations)
      .def_property_readonly("seconds_left", &RoundProblem::seconds_left)
      .def_property_readonly("iterations", &RoundProblem::iterations)
      .def("value", &RoundProblem::value)
      .def("gradient", &RoundProblem::gradient)
      .def("value_and_gradient", &RoundProblem::value_and_gradient)
      .def("iterate", &RoundProblem::iterate);
  m.def("_compare_optimizers", &compare_optimizers);

  py::class_<Objective>(m, "_Objective")
      .def(py::init<const Volume&, const Model&, const std::string&, const std::string&, double>())
      .def_property_readonly("size", &Objective::size)
      .def_property_readonly("samples", &Objective::samples)
      .def("value", &Objective::value)
      .def("gradient", &Objective::gradient)
      .def("value_and_gradient", &Objective::value_and_gradient)
      .def("residuals", &Objective::residuals)
      .def("jacobian", &Objective::jacobian);
}
