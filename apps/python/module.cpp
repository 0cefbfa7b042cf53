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
#include "apps/python/bindings.hpp"
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

namespace hisnegs::python {
namespace {

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
                           const std::optional<py::function>& progress, const Model* init) {
  const AppConfig config = config_of(config_text, "hisnegs.fit() options");
  apps::FitStart start;
  if (init != nullptr) {
    require_finite(*init, "hisnegs.fit(init=...)");
    start = apps::FitStart::of(init->checkpoint, volume.loaded.frame, "init");
  }
  auto m = std::make_shared<Model>();
  const apps::Progress sink = python_progress(progress);
  {
    py::gil_scoped_release release;
    m->checkpoint = apps::fit_loaded(volume.loaded, volume.loaded.volume.source, apps::FitConfig(config), sink,
                                     nullptr, start)
                        .checkpoint;
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

}  // namespace

AppConfig config_of(const std::string& config_text, const std::string& origin) {
  return apps::load_app_config_text(config_text, origin);
}

}  // namespace hisnegs::python

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
  m.def("_fit", &fit, py::arg("volume"), py::arg("config_text"), py::arg("progress"), py::arg("init").none(true));
  m.def("_info", &file_info);
  m.def("_export_vdb", &export_vdb);
  m.def("_export_volume", &export_volume);
  m.def("_export_compact", &export_compact);
  m.def("_export_html", &export_html);
  m.def("_train", &train);
  m.def("_ground_truth", &ground_truth);
  m.def("metrics", &metrics);

  bind_objective(m);
}
