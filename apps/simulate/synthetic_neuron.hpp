// SPDX-License-Identifier: Apache-2.0
// The bundled default data: a deterministic synthetic confocal stack of one neuron
// (soma, tapering varicose neurites, anisotropic PSF, Poisson-Gaussian camera noise,
// background subtraction). Owns the generator and its options; knows no file format.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

#include "io/error.hpp"  // io::InputError, thrown by validate()
#include "io/volume.hpp"

namespace hisnegs::simulate {

// Every knob of the simulated neuron and of its simulated acquisition. The volume is
// a deterministic function of these fields (same options, same build -> same voxels,
// whatever the number of threads). Config section `synth`; keys are field names.
struct SyntheticNeuronOptions {
  // --- stack geometry
  int nx = 192;                                       // stack columns (X), [8, 4096]
  int ny = 192;                                       // stack rows (Y), [8, 4096]
  int nz = 48;                                        // stack pages (Z), [8, 4096]
  std::array<double, 3> spacing_um{0.33, 0.33, 1.0};  // voxel size (x, y, z) in µm, each in (0, 100]
  std::uint64_t seed = 1;                             // seeds the morphology and the noise; any value

  // --- morphology (all lengths in µm, in the physical frame of the stack)
  int primary_branches = 5;                 // neurites leaving the soma, [1, 16]
  double soma_radius_um = 4.0;              // soma sphere radius, (0, 50]; must fit inside the box
  double max_radius_um = 1.0;               // primary neurite radius a few µm out of the soma (its trunk
                                            // widens to 1.8x at the soma), [min_radius_um, 10]
  double min_radius_um = 0.25;              // radius the neurites taper towards, (0, max_radius_um]
  double taper_length_um = 25.0;            // e-folding path length of the taper max -> min, (0, 1e4]
  double branch_probability_per_um = 0.06;  // chance per µm of path that a branch forks, [0, 1]
  int max_branch_order = 3;                 // forks per path from soma to tip at most, [0, 8]
  int max_branches = 64;                    // neurite pieces (primaries + forks) in all, [primary_branches, 1024]
  double max_path_length_um = 120;          // a neurite stops this far along its path from the soma, (0, 1e5]
  double step_um = 0.5;                     // skeleton node spacing along a neurite, [0.05, 5]
  double tortuosity = 0.15;                 // direction change per step: std dev (rad) per sqrt(µm), [0, 2]
  double outward_bias = 0.04;               // per-µm pull of the direction away from the soma, [0, 1]
  double planarity = 0.6;                   // how much z motion is damped (flat arbor), [0, 1]; 0 = isotropic
  double margin_um = 1.0;                   // skeleton keeps this far from every face of the box, [0, 1e4]
  double varicosity_period_um = 4.0;        // mean distance between varicosities (beads), (0, 1e4]
  double varicosity_radius_um = 0.3;        // mean radius a bead adds to its neurite, µm, [0, 10]
  double varicosity_length_um = 0.6;        // bead half-length (Gaussian std dev of the bump), (0, 100]

  // --- brightness: relative emitter density, soma = 1
  double neurite_brightness = 0.55;      // mean neurite density relative to the soma, (0, 0.9]
  double brightness_variation = 0.35;    // std dev of log density along a neurite, [0, 3]
  double brightness_correlation_um = 8;  // correlation length of that variation, (0, 1e4]
  // (neurite density is capped at 0.9 so the soma stays the brightest structure)

  // --- optics: Gaussian PSF std dev in µm (z is the optical axis)
  double psf_sigma_xy_um = 0.15;  // lateral PSF std dev, [0, 100]
  double psf_sigma_z_um = 0.6;    // axial PSF std dev, [0, 100]

  // --- detector: counts = gain * Poisson(photons) + Normal(0, read_noise) + camera_offset
  double peak_photons = 200;            // expected photons per voxel inside the soma, (0, 1e5]
  double background_photons = 0.5;      // expected autofluorescence photons per voxel, [0, 1e4]
  double gain_counts_per_photon = 1.0;  // camera counts per detected photon, (0, 100]
  double read_noise = 2.0;              // camera read noise std dev in counts, [0, 1e4]
  double camera_offset = 100;           // camera bias in counts, [0, 60000]

  // Background subtraction, part of the simulated acquisition (the shipped real stacks
  // were processed this way): subtract round(camera_offset + sigmas * read_noise)
  // counts and set what falls below 0 to 0, so most background voxels are exactly 0.
  bool background_subtract = true;          // apply the subtraction above
  double background_subtract_sigmas = 3.0;  // k in offset + k * read_noise, [0, 100]

  // Throws io::InputError("synth.FIELD = VALUE: rule broken") on the first
  // field outside its range (or soma + margins not fitting the box).
  void validate() const;

  // Calls v("name", field) once per field above, in declaration order, with name ==
  // the field's name (config loading, printing).
  template <class V>
  void visit(V&& v) {
    visit_fields(*this, v);
  }
  template <class V>
  void visit(V&& v) const {
    visit_fields(*this, v);
  }

 private:
  template <class Self, class V>
  static void visit_fields(Self& s, V& v) {
    v("nx", s.nx);
    v("ny", s.ny);
    v("nz", s.nz);
    v("spacing_um", s.spacing_um);
    v("seed", s.seed);
    v("primary_branches", s.primary_branches);
    v("soma_radius_um", s.soma_radius_um);
    v("max_radius_um", s.max_radius_um);
    v("min_radius_um", s.min_radius_um);
    v("taper_length_um", s.taper_length_um);
    v("branch_probability_per_um", s.branch_probability_per_um);
    v("max_branch_order", s.max_branch_order);
    v("max_branches", s.max_branches);
    v("max_path_length_um", s.max_path_length_um);
    v("step_um", s.step_um);
    v("tortuosity", s.tortuosity);
    v("outward_bias", s.outward_bias);
    v("planarity", s.planarity);
    v("margin_um", s.margin_um);
    v("varicosity_period_um", s.varicosity_period_um);
    v("varicosity_radius_um", s.varicosity_radius_um);
    v("varicosity_length_um", s.varicosity_length_um);
    v("neurite_brightness", s.neurite_brightness);
    v("brightness_variation", s.brightness_variation);
    v("brightness_correlation_um", s.brightness_correlation_um);
    v("psf_sigma_xy_um", s.psf_sigma_xy_um);
    v("psf_sigma_z_um", s.psf_sigma_z_um);
    v("peak_photons", s.peak_photons);
    v("background_photons", s.background_photons);
    v("gain_counts_per_photon", s.gain_counts_per_photon);
    v("read_noise", s.read_noise);
    v("camera_offset", s.camera_offset);
    v("background_subtract", s.background_subtract);
    v("background_subtract_sigmas", s.background_subtract_sigmas);
  }
};

// One node of the ground-truth skeleton. Positions are in µm in the stack's index
// frame: voxel (i, j, k) has its centre at (i sx, j sy, k sz), so position_um / spacing
// is the continuous (column, row, page) index. Node 0 is the soma centre (radius =
// soma_radius_um, parent -1); every other node's parent comes before it.
struct NeuriteNode {
  Eigen::Vector3d position_um{0, 0, 0};
  double radius_um = 0;   // local tube radius, varicosities included
  int parent = -1;        // index of the parent node, -1 for the soma
  double brightness = 1;  // relative emitter density (soma = 1)
};

// What the simulated acquisition clamped (STYLE: clamping is counted).
struct SyntheticNeuronCounts {
  std::int64_t clipped_to_zero = 0;  // voxels the background subtraction set to 0
  std::int64_t saturated = 0;        // voxels clipped at 65535 counts
};

// Generates the stack: raw camera counts (background-subtracted if the option says
// so) as a io::Volume of shape (options.nx, ny, nz) holding integral values in [0, 65535],
// stored_as = kUint16, spacing = options.spacing_um (io::SpacingSource::kUser), source =
// "synthetic (seed N)", normalization kNone. Optionally returns the ground-truth
// skeleton and the clamp counts (either pointer may be null). Throws io::InputError
// from options.validate(). Uses TBB; the result does not depend on the thread count.
[[nodiscard]] io::Volume make_synthetic_neuron(const SyntheticNeuronOptions& options,
                                           std::vector<NeuriteNode>* skeleton = nullptr,
                                           SyntheticNeuronCounts* counts = nullptr);

}  // namespace hisnegs::simulate
