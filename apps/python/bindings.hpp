// SPDX-License-Identifier: Apache-2.0
// What the files of the Python module share: the objects Python holds (a Volume, a
// Model), the options of a call, and the casters that refuse an object whose
// __init__ never ran. module.cpp binds volumes, cameras, models, exports, ground
// truth and metrics; objective.cpp the stage-1 objective and Python optimizers.
#pragma once

#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <string>

#include "apps/pipeline/app_config.hpp"
#include "gmf/core/checkpoint.hpp"
#include "io/load_volume.hpp"
#include "splat/camera.hpp"

namespace py = pybind11;

namespace hisnegs::python {

using apps::AppConfig;
using FloatArray = py::array_t<float, py::array::c_style | py::array::forcecast>;
using DoubleArray = py::array_t<double, py::array::c_style | py::array::forcecast>;

struct Volume {
  io::LoadedVolume loaded;  // its volume.source names the file, or "numpy array"
};

struct Model {
  gmf::Checkpoint checkpoint;
};

class RoundProblem;
class Objective;

// The options of a call: the built-in defaults overlaid with `config_text` (YAML of
// the sections given as keyword arguments), validated; errors name `origin`.
[[nodiscard]] AppConfig config_of(const std::string& config_text, const std::string& origin);

// Binds the stage-1 objective (_Objective), RoundProblem, StopRound and
// _compare_optimizers (objective.cpp).
void bind_objective(py::module_& m);

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
