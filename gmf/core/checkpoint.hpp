// SPDX-License-Identifier: Apache-2.0
// The checkpoint file (CONVENTIONS "Files → Checkpoint"): the mapping between a
// GaussianMixture plus its metadata and io's generic PLY table, saving / loading
// it, and the stack frame its metadata record. Does not parse PLY itself
// (io/ply.hpp) nor know about fitting.
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "gmf/core/aggregation.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/core/background.hpp"
#include "io/ply.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

// The newest checkpoint format this build reads and the one it writes.
inline constexpr int kCheckpointFormatVersion = 1;

// What a checkpoint records besides the Gaussians, one `comment hisnegs KEY VALUE`
// header line each (absent optionals / an empty normalization write no line).
struct CheckpointMeta {
  int format_version = kCheckpointFormatVersion;       // "comment hisnegs format_version 1"
  std::optional<std::array<int, 3>> volume_shape_zyx;  // "volume_shape Z Y X", each > 0
  std::optional<std::array<double, 3>> spacing_um;     // "spacing_um sx sy sz", µm, finite > 0
  std::optional<std::array<double, 3>> aspect;         // "aspect ax ay az", world half-extents, finite > 0
  std::string normalization;  // "normalization minmax 0 254": free text after the key, verbatim
  // How the model's terms combine ("aggregation softmax 64"; no line, and files
  // without one: a sum, report Eq. 1). Every 3D evaluation of the model uses it.
  Aggregation aggregation = Aggregation::kSum;
  double beta = 0.0;  // softmax β, finite > 0 (0 for a sum)
  // Any other "comment hisnegs KEY VALUE" line, in file order. KEY is one token
  // (no whitespace, not a known key); VALUE is the rest of the line after one
  // blank, verbatim (may be empty, no line breaks).
  std::vector<std::pair<std::string, std::string>> extra;

  friend bool operator==(const CheckpointMeta&, const CheckpointMeta&) = default;
};

struct Checkpoint {
  GaussianMixture mixture;
  CheckpointMeta meta;
};

// Builds the checkpoint's PLY table: one `vertex` element with K rows of float
// properties x y z scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3
// intensity_logit (log-scales; rot = w x y z) and the `hisnegs` comments in the
// order format_version, volume_shape, spacing_um, aspect, normalization, extra.
// Doubles are written in the shortest form that reads back bit-identical.
// Throws std::invalid_argument ("gaussian 17: scale_1 is nan") for a
// non-finite parameter or an all-zero quaternion, and for metadata it could not
// read back (format_version other than kCheckpointFormatVersion, a non-positive
// shape / spacing / aspect, a line break, a bad or known key in `extra`).
[[nodiscard]] io::PlyTable checkpoint_to_ply(const GaussianMixture& mixture, const CheckpointMeta& meta);

// The inverse of checkpoint_to_ply for any table read from `source` (named in
// messages). Accepts the properties in any order, as float or double, next to
// extra properties (e.g. a 3DGS viewer's f_dc_0) and extra elements, all
// ignored; comments not starting with "hisnegs" are ignored; a missing
// format_version line means version 1. K = 0 (an empty `vertex` element) is a
// valid, empty model. Throws io::InputError, one line "SOURCE: problem", for: no
// `vertex` element, a missing required property or one of another type, a
// non-finite value ("vertex 17: scale_1 is nan"), a double outside float range,
// an all-zero quaternion, a format_version newer than kCheckpointFormatVersion
// (or < 1), a malformed value of a known key ("comment hisnegs volume_shape ...")
// or a known key given twice.
[[nodiscard]] Checkpoint checkpoint_from_ply(const io::PlyTable& table, const std::filesystem::path& source);

// The metadata lines of a checkpoint, each "hisnegs KEY VALUE" (the PLY header's
// comment lines without "comment "), in checkpoint_to_ply's order. Throws
// std::invalid_argument for metadata it could not read back, as checkpoint_to_ply.
// The compact format (gmf/core/compact_checkpoint.hpp) stores the same lines.
[[nodiscard]] std::vector<std::string> checkpoint_comments(const CheckpointMeta& meta);

// The vertex properties a checkpoint writes: kGaussianParamNames, float32 each.
[[nodiscard]] std::vector<io::PlyProperty> checkpoint_properties();

// Throws std::invalid_argument ("gaussian 17: scale_1 is nan") for the first
// Gaussian no checkpoint may hold: a non-finite parameter or an all-zero quaternion.
void check_checkpoint_mixture(const GaussianMixture& mixture);

// The inverse of checkpoint_comments: parses the "hisnegs KEY VALUE" lines among
// `comments` (others are ignored) as checkpoint_from_ply does, with its errors
// (io::InputError "SOURCE: comment hisnegs volume_shape: ...").
[[nodiscard]] CheckpointMeta checkpoint_meta_from_comments(const std::vector<std::string>& comments,
                                                           const std::filesystem::path& source);

// Writes a checkpoint atomically (temp file + rename) as binary little-endian
// PLY. Throws std::invalid_argument "PATH: ..." as checkpoint_to_ply does
// (nothing is written then), io::InputError / std::runtime_error if the file
// cannot be written.
void save_checkpoint(const std::filesystem::path& path, const GaussianMixture& mixture, const CheckpointMeta& meta);

// save_checkpoint for a model that arrives in pieces, in order (one too large to
// hold whole: the bricked fit writes brick after brick). Give the count first,
// append() every Gaussian, then commit(); the file equals save_checkpoint's of the
// same Gaussians and metadata. Destroyed without commit() (an exception), nothing
// is left. Throws as save_checkpoint does; std::logic_error for more or fewer
// Gaussians than `count`.
class CheckpointWriter {
 public:
  CheckpointWriter(const std::filesystem::path& path, const CheckpointMeta& meta, std::size_t count);
  void append(std::span<const GaussianParams> gaussians);
  void commit();

 private:
  std::filesystem::path path_;
  io::PlyRowWriter rows_;
  std::size_t appended_ = 0;
};

// Reads a checkpoint written by save_checkpoint (or by another tool using the
// same properties) or by save_compact_checkpoint (gmf/core/compact_checkpoint.hpp):
// the file's first bytes decide, not its name. Throws io::InputError naming the
// file for every problem of io::read_ply and checkpoint_from_ply, or of
// load_compact_checkpoint.
[[nodiscard]] Checkpoint load_checkpoint(const std::filesystem::path& path);

// The mixture model a checkpoint's 3D value uses: its aggregation and β with the
// given Mahalanobis cutoff δ.
[[nodiscard]] MixtureModel model_of(const CheckpointMeta& meta, double cutoff = 16.0);

// "sum" or "softmax (beta 64)": which f a model's 3D value is, for progress lines.
[[nodiscard]] std::string describe(const MixtureModel& model);

// The frame of the stack a checkpoint was fitted to, from its `volume_shape` and
// `aspect` metadata; nullopt when either is missing (e.g. a model made elsewhere).
[[nodiscard]] std::optional<io::WorldFrame> model_frame(const CheckpointMeta& meta);

// The background a checkpoint records ("comment hisnegs background ..." in the
// gmf::BackgroundModel text form): what a ray through the stack samples of its noise,
// from which renders draw the MIP's floor. A checkpoint without the line (every file
// before it, and fits of zero-background stacks) has none: an empty model. Throws
// io::InputError naming `source` for a line that does not parse.
[[nodiscard]] gmf::BackgroundModel background_of(const CheckpointMeta& meta, const std::string& source);
// Records `model` in `meta` (replacing any earlier one); a none() model removes it.
void set_background(CheckpointMeta& meta, const gmf::BackgroundModel& model);
// The background by region: `merged` from the "background" line; with a
// "background_regions CX CY CZ" line, one "background_region R MODEL" line per region
// (R = 0, 1, ... in order) over the stack of `volume_shape`. Throws io::InputError
// naming `source` for lines that do not parse or do not match.
[[nodiscard]] gmf::BackgroundField background_field_of(const CheckpointMeta& meta, const std::string& source);
// Records `field` (replacing any earlier background): its merged model as
// set_background does, and its regions when it has several.
void set_background(CheckpointMeta& meta, const gmf::BackgroundField& field);

// Checks that `frame` (the stack `volume`) spans the same world box as the stack the
// model was fitted to (its `aspect` metadata, relative tolerance 1e-6), so that the
// model's Gaussians sit on that stack's voxels. Does nothing when the checkpoint
// records no aspect. Throws io::InputError naming `volume` and both aspects otherwise
// (a different --spacing or --aspect than the fit used gives a different box).
void require_same_world_box(const CheckpointMeta& meta, const io::WorldFrame& frame, const std::string& volume);

}  // namespace hisnegs::gmf
