// SPDX-License-Identifier: Apache-2.0
// Tests of gmf/core/gaussian_mixture.hpp (container, R(q), Σ, reference evaluator,
// stats) and gmf/core/checkpoint.hpp (bit-exact round trips, accepted variants,
// every rejected checkpoint). Every fixture is generated here.
#include "gmf/core/checkpoint.hpp"

#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>
#include <numbers>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"
#include "io/error.hpp"
#include "io/ply.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::gmf {
namespace {
namespace fs = std::filesystem;
using hisnegs::testing::ScratchDir;

GaussianMixture random_mixture(std::size_t k, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> mean(-1.0f, 1.0f), log_scale(-5.0f, -1.0f), logit(-4.0f, 4.0f);
  std::normal_distribution<float> quat(0.0f, 1.0f);
  GaussianMixture m;
  for (std::size_t i = 0; i < k; ++i) {
    GaussianParams g;
    for (float& v : g.mean) v = mean(rng);
    for (float& v : g.log_scale) v = log_scale(rng);
    for (float& v : g.rotation) v = quat(rng);  // not unit on purpose
    g.intensity_logit = logit(rng);
    m.push_back(g);
  }
  return m;
}

bool bit_equal(const GaussianMixture& a, const GaussianMixture& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(GaussianParams)) == 0);
}

CheckpointMeta full_meta() {
  CheckpointMeta meta;
  meta.volume_shape_zyx = std::array<int, 3>{60, 512, 512};
  meta.spacing_um = std::array<double, 3>{0.3296, 0.3296, 0.9988};
  meta.aspect = std::array<double, 3>{1.0, 1.0, 60 * 0.9988 / (512 * 0.3296)};  // not a short decimal
  meta.normalization = "minmax 0 254";
  meta.extra = {{"trainer", "soft-mip v2"}, {"empty_value", ""}, {"spaced", "  two leading blanks"}};
  return meta;
}

// A vertex element with properties `names` (in that order, of type `type`) taken
// from `m`; names outside kGaussianParamNames get zeros (like a viewer's f_dc_0).
io::PlyTable make_table(const GaussianMixture& m, const std::vector<std::string>& names,
                        io::PlyType type = io::PlyType::kFloat32,
                        std::vector<std::string> comments = {"hisnegs format_version 1"}) {
  io::PlyTable table;
  table.comments = std::move(comments);
  io::PlyElement vertex("vertex");
  for (const std::string& name : names) {
    std::vector<double> values(m.size(), 0.0);
    for (std::size_t j = 0; j < kGaussianParamCount; ++j) {
      if (kGaussianParamNames[j] != name) continue;
      for (std::size_t k = 0; k < m.size(); ++k) values[k] = to_array(m[k])[j];
    }
    vertex.add_column<double>(name, type, values);
  }
  table.elements.push_back(std::move(vertex));
  return table;
}

// The shortest decimal that reads back to `v` (what the checkpoint writes).
std::string shortest(double v) {
  char buf[64];
  return std::string(buf, std::to_chars(buf, buf + sizeof buf, v).ptr);
}

std::vector<std::string> param_names() { return {kGaussianParamNames.begin(), kGaussianParamNames.end()}; }

// Expects load_checkpoint(path) to throw a one-line InputError naming the file and containing `expected`.
void expect_load_error(const fs::path& path, const std::string& expected) {
  try {
    (void)load_checkpoint(path);
    ADD_FAILURE() << "load_checkpoint accepted " << path << " (expected '" << expected << "')";
  } catch (const io::InputError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find(path.string()), std::string::npos) << message;
    EXPECT_NE(message.find(expected), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  }
}

// ----- GaussianMixture -----

TEST(GaussianMixture, ContainerBasics) {
  GaussianMixture m;
  EXPECT_TRUE(m.empty());
  GaussianParams g;
  g.mean = {1.0f, 2.0f, 3.0f};
  m.push_back(g);
  m.resize(3);
  ASSERT_EQ(m.size(), 3u);
  EXPECT_EQ(m[0].mean[2], 3.0f);
  // New entries are the default unit Gaussian with a usable rotation.
  EXPECT_EQ(m[2].rotation, (std::array<float, 4>{1.0f, 0.0f, 0.0f, 0.0f}));
  int n = 0;
  for (const GaussianParams& p : m) n += p.log_scale[0] == 0.0f;
  EXPECT_EQ(n, 3);
  EXPECT_EQ(m.data(), &m[0]);
  const GaussianParams back = from_array(to_array(g));
  EXPECT_EQ(std::memcmp(&back, &g, sizeof g), 0);
  EXPECT_EQ(to_array(g)[2], 3.0f);
  EXPECT_EQ(to_array(g)[6], 1.0f);  // rot_0 = w
  m.clear();
  EXPECT_TRUE(m.empty());
}

TEST(GaussianMixture, SigmoidIsStableForLargeLogits) {
  EXPECT_EQ(sigmoid(0.0), 0.5);
  EXPECT_EQ(sigmoid(1000.0), 1.0);
  EXPECT_EQ(sigmoid(-1000.0), 0.0);
  EXPECT_EQ(sigmoid(-100.0f), std::exp(-100.0f) / (1.0f + std::exp(-100.0f)));
  EXPECT_NEAR(sigmoid(std::log(3.0)), 0.75, 1e-15);
}

TEST(GaussianMixture, RotationMatrixMatchesKnownRotationAndIsOrthonormal) {
  // q = 2 (cos 30°, 0, 0, sin 30°): a 60° turn about z, deliberately not unit.
  const double c = std::cos(std::numbers::pi / 6), s = std::sin(std::numbers::pi / 6);
  const Eigen::Matrix3d r = rotation_matrix(Eigen::Vector4d(2 * c, 0, 0, 2 * s));
  Eigen::Matrix3d expected;
  expected << 0.5, -std::sqrt(3.0) / 2, 0, std::sqrt(3.0) / 2, 0.5, 0, 0, 0, 1;
  EXPECT_LT((r - expected).cwiseAbs().maxCoeff(), 1e-15);

  for (const GaussianParams& g : random_mixture(50, 3)) {
    const Eigen::Matrix3d q = rotation_matrix(g);
    EXPECT_LT((q.transpose() * q - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(), 1e-14);
    EXPECT_NEAR(q.determinant(), 1.0, 1e-14);
  }
  EXPECT_THROW((void)rotation_matrix(Eigen::Vector4d::Zero().eval()), std::invalid_argument);
}

// A Gaussian whose first axis (s = 0.2) is turned 90° about z onto world y, its
// second axis (s = 1) onto world -x; third axis (s = 0.5) stays on z. a = 0.75.
GaussianParams rotated_anisotropic() {
  GaussianParams g;
  g.mean = {0.25f, -0.5f, 0.125f};
  g.log_scale = {static_cast<float>(std::log(0.2)), 0.0f, static_cast<float>(std::log(0.5))};
  const float h = static_cast<float>(std::sqrt(0.5));
  g.rotation = {2 * h, 0.0f, 0.0f, 2 * h};  // not unit: normalized before use
  g.intensity_logit = static_cast<float>(std::log(3.0));
  return g;
}

TEST(GaussianMixture, CovarianceIsRotatedDiagonal) {
  // Σ = R diag(0.04, 1, 0.25) Rᵀ with R e_x = e_y, R e_y = -e_x: diag(1, 0.04, 0.25).
  // Tolerance: log-scales and q are stored as float (relative error ~6e-8).
  const Eigen::Matrix3d sigma = covariance(rotated_anisotropic());
  const Eigen::Matrix3d expected = Eigen::Vector3d(1.0, 0.04, 0.25).asDiagonal();
  EXPECT_LT((sigma - expected).cwiseAbs().maxCoeff(), 1e-6);
}

TEST(GaussianMixture, CovarianceIsSymmetricPositiveDefinite) {
  for (const GaussianParams& g : random_mixture(100, 11)) {
    const Eigen::Matrix3d sigma = covariance(g);
    const Eigen::Matrix3d r = rotation_matrix(g);
    const Eigen::Vector3d s = scales(g);
    const Eigen::Matrix3d expected = r * Eigen::Vector3d(s.array().square()).asDiagonal() * r.transpose();
    EXPECT_LT((sigma - expected).cwiseAbs().maxCoeff(), 1e-15);
    EXPECT_EQ(sigma, sigma.transpose());  // exactly: Σ_ij and Σ_ji are the same sums
    EXPECT_EQ(Eigen::LLT<Eigen::Matrix3d>(sigma).info(), Eigen::Success);
    // Its eigenvalues are the squared scales.
    Eigen::Vector3d eig = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(sigma).eigenvalues();
    Eigen::Vector3d s2 = s.array().square();
    std::sort(s2.begin(), s2.end());
    EXPECT_LT(((eig - s2).array() / s2.array()).abs().maxCoeff(), 1e-9);
  }
}

TEST(GaussianMixture, EvaluateIsotropicMatchesHandValue) {
  GaussianParams g;  // s = 1, a = sigmoid(0) = 0.5, all values exact in float
  g.mean = {0.25f, 0.5f, -0.75f};
  GaussianMixture m;
  m.push_back(g);
  // d = (0.6, 0.8, 0): |d|² = 1, f = 0.5 exp(-1/2).
  EXPECT_NEAR(evaluate_mixture(m, Eigen::Vector3d(0.85, 1.3, -0.75)), 0.5 * std::exp(-0.5), 1e-15);
  EXPECT_EQ(evaluate_mixture(m, Eigen::Vector3d(0.25, 0.5, -0.75)), 0.5);
}

TEST(GaussianMixture, EvaluateRotatedAnisotropicMatchesHandValue) {
  GaussianMixture m;
  m.push_back(rotated_anisotropic());
  // d = (0.5, 0.1, 0.25); in the Gaussian's frame Rᵀd = (0.1, -0.5, 0.25), so
  // dᵀΣ⁻¹d = (0.1/0.2)² + (0.5/1)² + (0.25/0.5)² = 0.75 and f = 0.75 exp(-0.375).
  // Tolerance: float-stored log-scales, q and logit (relative error ~1e-7).
  const Eigen::Vector3d x(0.75, -0.4, 0.375);
  const double expected = 0.75 * std::exp(-0.375);
  EXPECT_NEAR(evaluate_mixture(m, x), expected, 1e-6 * expected);
  // The same value through Σ⁻¹ explicitly.
  const Eigen::Vector3d d = x - Eigen::Vector3d(0.25, -0.5, 0.125);
  EXPECT_NEAR(evaluate_mixture(m, x), 0.75 * std::exp(-0.5 * d.dot(covariance(m[0]).inverse() * d)), 1e-6);
}

TEST(GaussianMixture, EvaluateSumsOverGaussians) {
  GaussianMixture both = random_mixture(5, 21);
  const Eigen::Vector3d x(0.1, -0.2, 0.3);
  double sum = 0;
  for (const GaussianParams& g : both) sum += evaluate_mixture(GaussianMixture({g}), x);
  EXPECT_NEAR(evaluate_mixture(both, x), sum, 1e-15);
  EXPECT_EQ(evaluate_mixture(GaussianMixture(), x), 0.0);
}

TEST(GaussianMixture, StatsOfSmallMixture) {
  GaussianParams a, b;
  a.mean = {-1.0f, 0.0f, 2.0f};
  b.mean = {3.0f, 0.0f, 4.0f};
  a.log_scale = {0.0f, 0.0f, 0.0f};
  b.log_scale = {static_cast<float>(std::log(3.0)), 0.0f, 0.0f};
  a.intensity_logit = 0.0f;
  b.intensity_logit = static_cast<float>(std::log(3.0));
  const MixtureStats st = compute_stats(GaussianMixture({a, b}));
  EXPECT_EQ(st.count, 2u);
  EXPECT_EQ(st.params[0].min, -1.0);
  EXPECT_EQ(st.params[0].max, 3.0);
  EXPECT_EQ(st.params[0].mean, 1.0);
  EXPECT_EQ(st.params[2].mean, 3.0);
  EXPECT_EQ(st.params[6].min, 1.0);  // rot_0 = w of two default quaternions
  EXPECT_NEAR(st.mean_scale[0], 2.0, 1e-6);
  EXPECT_EQ(st.mean_scale[1], 1.0);
  EXPECT_EQ(st.intensity_min, 0.5);
  EXPECT_NEAR(st.intensity_max, 0.75, 1e-7);
  EXPECT_NEAR(st.intensity_mean, 0.625, 1e-7);

  const MixtureStats empty = compute_stats(GaussianMixture());
  EXPECT_EQ(empty.count, 0u);
  EXPECT_EQ(empty.params[0].min, 0.0);
  EXPECT_EQ(empty.intensity_max, 0.0);
}

// ----- checkpoint round trips -----

TEST(Checkpoint, RandomMixtureRoundTripIsBitIdentical) {
  ScratchDir dir;
  const GaussianMixture m = random_mixture(1000, 42);
  const CheckpointMeta meta = full_meta();
  save_checkpoint(dir / "model.ply", m, meta);
  const Checkpoint c = load_checkpoint(dir / "model.ply");
  EXPECT_TRUE(bit_equal(c.mixture, m));
  EXPECT_EQ(c.meta, meta);  // doubles compared exactly
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"model.ply"});
}

// The bricked fit's rank 0 writes the checkpoint brick after brick.
TEST(Checkpoint, AWriterOfPiecesWritesTheBytesOfSaveCheckpoint) {
  ScratchDir dir;
  const GaussianMixture m = random_mixture(1000, 7);
  save_checkpoint(dir / "whole.ply", m, full_meta());
  CheckpointWriter writer(dir / "pieces.ply", full_meta(), m.size());
  const std::span<const GaussianParams> all = m.params();
  writer.append(all.subspan(0, 0));
  writer.append(all.subspan(0, 333));
  writer.append(all.subspan(333));
  writer.commit();
  EXPECT_EQ(hisnegs::testing::read_bytes(dir / "pieces.ply"), hisnegs::testing::read_bytes(dir / "whole.ply"));
}

TEST(Checkpoint, AWriterGivenTooFewOrBadGaussiansLeavesNoFile) {
  ScratchDir dir;
  const GaussianMixture m = random_mixture(10, 8);
  {
    CheckpointWriter writer(dir / "short.ply", CheckpointMeta(), 11);
    writer.append(m.params());
    EXPECT_THROW(writer.commit(), std::logic_error);
  }
  {
    CheckpointWriter writer(dir / "long.ply", CheckpointMeta(), 9);
    EXPECT_THROW(writer.append(m.params()), std::logic_error);
  }
  GaussianMixture bad = m;
  bad[4].log_scale[1] = std::numeric_limits<float>::quiet_NaN();
  try {
    CheckpointWriter writer(dir / "bad.ply", CheckpointMeta(), 20);
    writer.append(m.params());
    writer.append(bad.params());
    FAIL() << "a NaN was written";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("gaussian 14: scale_1 is nan"), std::string::npos) << e.what();
  }
  EXPECT_TRUE(dir.entries().empty());
}

TEST(Checkpoint, EmptyMixtureIsAValidModel) {
  ScratchDir dir;
  save_checkpoint(dir / "empty.ply", GaussianMixture(), CheckpointMeta());
  const Checkpoint c = load_checkpoint(dir / "empty.ply");
  EXPECT_TRUE(c.mixture.empty());
  EXPECT_EQ(c.meta, CheckpointMeta());
  EXPECT_EQ(io::read_ply(dir / "empty.ply").find("vertex")->count(), 0);
}

TEST(Checkpoint, FileLayoutFollowsConventions) {
  ScratchDir dir;
  save_checkpoint(dir / "m.ply", random_mixture(3, 1), full_meta());
  const io::PlyTable t = io::read_ply(dir / "m.ply");
  ASSERT_EQ(t.elements.size(), 1u);
  const io::PlyElement& v = t.elements[0];
  EXPECT_EQ(v.name(), "vertex");
  ASSERT_EQ(v.properties().size(), kGaussianParamCount);
  for (std::size_t j = 0; j < kGaussianParamCount; ++j) {
    EXPECT_EQ(v.properties()[j].name, kGaussianParamNames[j]);
    EXPECT_EQ(v.properties()[j].type, io::PlyType::kFloat32);
  }
  const std::vector<std::string> expected = {"hisnegs format_version 1",
                                             "hisnegs volume_shape 60 512 512",
                                             "hisnegs spacing_um 0.3296 0.3296 0.9988",
                                             "hisnegs aspect 1 1 " + shortest(60 * 0.9988 / (512 * 0.3296)),
                                             "hisnegs normalization minmax 0 254",
                                             "hisnegs trainer soft-mip v2",
                                             "hisnegs empty_value",
                                             "hisnegs spaced   two leading blanks"};
  EXPECT_EQ(t.comments, expected);
  EXPECT_EQ(v.column_as<float>("x")[2], random_mixture(3, 1)[2].mean[0]);
}

TEST(Checkpoint, ReorderedPropertiesWithExtrasAreAccepted) {
  ScratchDir dir;
  const GaussianMixture m = random_mixture(20, 5);
  std::vector<std::string> names = param_names();
  std::reverse(names.begin(), names.end());
  names.insert(names.begin() + 3, "f_dc_0");
  names.push_back("opacity");
  io::write_ply(dir / "r.ply", make_table(m, names));
  EXPECT_TRUE(bit_equal(load_checkpoint(dir / "r.ply").mixture, m));
}

TEST(Checkpoint, DoublePropertiesAreAccepted) {
  ScratchDir dir;
  const GaussianMixture m = random_mixture(20, 6);
  io::write_ply(dir / "d.ply", make_table(m, param_names(), io::PlyType::kFloat64));
  EXPECT_TRUE(bit_equal(load_checkpoint(dir / "d.ply").mixture, m));  // float -> double -> float is exact
}

TEST(Checkpoint, MissingFormatVersionMeansVersionOne) {
  ScratchDir dir;
  io::write_ply(dir / "v.ply", make_table(random_mixture(2, 7), param_names(), io::PlyType::kFloat32, {}));
  EXPECT_EQ(load_checkpoint(dir / "v.ply").meta.format_version, 1);
}

TEST(Checkpoint, UnknownKeysAreKeptAndForeignCommentsIgnored) {
  ScratchDir dir;
  io::write_ply(dir / "k.ply", make_table(random_mixture(2, 8), param_names(), io::PlyType::kFloat32,
                                          {"made by some viewer", "hisnegsish not ours", "hisnegs trainer soft",
                                           "hisnegs format_version 1", "hisnegs note", "hisnegs trainer again"}));
  const CheckpointMeta meta = load_checkpoint(dir / "k.ply").meta;
  const std::vector<std::pair<std::string, std::string>> expected = {
      {"trainer", "soft"}, {"note", ""}, {"trainer", "again"}};
  EXPECT_EQ(meta.extra, expected);
  EXPECT_FALSE(meta.volume_shape_zyx.has_value());
  EXPECT_TRUE(meta.normalization.empty());
}

// ----- rejected checkpoints -----

TEST(Checkpoint, MissingPropertyIsRejected) {
  ScratchDir dir;
  std::vector<std::string> names = param_names();
  names.erase(names.begin() + 8);  // rot_2
  io::write_ply(dir / "m.ply", make_table(random_mixture(4, 9), names));
  expect_load_error(dir / "m.ply", "vertex element has no property 'rot_2'");
}

TEST(Checkpoint, NanIsRejectedNamingVertexAndProperty) {
  ScratchDir dir;
  GaussianMixture m = random_mixture(20, 10);
  m[17].log_scale[1] = std::numeric_limits<float>::quiet_NaN();
  io::write_ply(dir / "n.ply", make_table(m, param_names()));
  expect_load_error(dir / "n.ply", "vertex 17: scale_1 is nan");
  // The same through the general (reordered) layout, with a later zero quaternion.
  m[18].rotation = {0.0f, 0.0f, 0.0f, 0.0f};
  std::vector<std::string> names = param_names();
  std::reverse(names.begin(), names.end());
  io::write_ply(dir / "r.ply", make_table(m, names));
  expect_load_error(dir / "r.ply", "vertex 17: scale_1 is nan");
}

TEST(Checkpoint, InfIsRejectedNamingVertexAndProperty) {
  ScratchDir dir;
  GaussianMixture m = random_mixture(5, 12);
  m[3].mean[0] = -std::numeric_limits<float>::infinity();
  io::write_ply(dir / "i.ply", make_table(m, param_names(), io::PlyType::kFloat64));
  expect_load_error(dir / "i.ply", "vertex 3: x is -inf");
}

TEST(Checkpoint, DoubleOutsideFloatRangeIsRejected) {
  ScratchDir dir;
  io::PlyTable t = make_table(random_mixture(2, 13), param_names(), io::PlyType::kFloat64);
  io::PlyElement& v = t.elements[0];
  v.set_column<double>(*v.find_property("intensity_logit"), std::vector<double>{0.0, 1e300});
  io::write_ply(dir / "big.ply", t);
  expect_load_error(dir / "big.ply", "vertex 1: intensity_logit = 1e+300 is outside the float32 range");
}

TEST(Checkpoint, ZeroQuaternionIsRejected) {
  ScratchDir dir;
  GaussianMixture m = random_mixture(3, 14);
  m[2].rotation = {0.0f, -0.0f, 0.0f, 0.0f};
  io::write_ply(dir / "q.ply", make_table(m, param_names()));
  expect_load_error(dir / "q.ply", "vertex 2: rotation rot_0..rot_3 is all zero");
}

TEST(Checkpoint, IntegerPropertyIsRejected) {
  ScratchDir dir;
  io::PlyTable t = make_table(random_mixture(0, 15), param_names());
  t.elements[0].add_column<std::uint8_t>("red", std::vector<std::uint8_t>{});  // extras may be any type
  io::write_ply(dir / "ok.ply", t);
  EXPECT_NO_THROW((void)load_checkpoint(dir / "ok.ply"));

  std::vector<std::string> names = param_names();
  names.erase(names.begin());  // x, re-added as int
  io::PlyTable bad = make_table(random_mixture(0, 15), names);
  bad.elements[0].add_column<std::int32_t>("x", std::vector<std::int32_t>{});
  io::write_ply(dir / "bad.ply", bad);
  expect_load_error(dir / "bad.ply", "vertex property 'x' has type int, expected float or double");
}

TEST(Checkpoint, CutShortFileIsRejected) {
  ScratchDir dir;
  save_checkpoint(dir / "c.ply", random_mixture(10, 16), CheckpointMeta());
  fs::resize_file(dir / "c.ply", fs::file_size(dir / "c.ply") - 10);
  expect_load_error(dir / "c.ply", "expected 440 bytes of vertex data, file has 430");
}

TEST(Checkpoint, NoVertexElementIsRejected) {
  ScratchDir dir;
  io::PlyTable t;
  t.elements.emplace_back("face", 0, std::vector<io::PlyProperty>{{"a", io::PlyType::kFloat32}});
  io::write_ply(dir / "f.ply", t);
  expect_load_error(dir / "f.ply", "no 'vertex' element");
}

TEST(Checkpoint, MissingFileIsInputError) {
  ScratchDir dir;
  expect_load_error(dir / "absent.ply", "no such file");
}

TEST(Checkpoint, NewerFormatVersionIsRejected) {
  ScratchDir dir;
  io::write_ply(dir / "v2.ply",
                make_table(random_mixture(2, 17), param_names(), io::PlyType::kFloat32, {"hisnegs format_version 2"}));
  expect_load_error(dir / "v2.ply", "format_version 2 is newer than this build supports (1)");
}

struct BadComment {
  const char* name;
  const char* comment;
  const char* expected;
};

class CheckpointBadMeta : public ::testing::TestWithParam<BadComment> {};

TEST_P(CheckpointBadMeta, MalformedKnownKeyIsRejectedNamingTheKey) {
  ScratchDir dir;
  io::write_ply(dir / "m.ply", make_table(random_mixture(1, 18), param_names(), io::PlyType::kFloat32,
                                          {"hisnegs format_version 1", GetParam().comment}));
  expect_load_error(dir / "m.ply", GetParam().expected);
}

INSTANTIATE_TEST_SUITE_P(
    Checkpoint, CheckpointBadMeta,
    ::testing::Values(
        BadComment{"shape_not_int", "hisnegs volume_shape 60 abc 512",
                   "comment hisnegs volume_shape: expected three positive integers Z Y X, got '60 abc 512'"},
        BadComment{"shape_two_values", "hisnegs volume_shape 60 512", "volume_shape"},
        BadComment{"shape_zero", "hisnegs volume_shape 0 1 1", "volume_shape"},
        BadComment{"spacing_nan", "hisnegs spacing_um 1 nan 1", "spacing_um"},
        BadComment{"spacing_negative", "hisnegs spacing_um 1 1 -2", "spacing_um"},
        BadComment{"aspect_text", "hisnegs aspect 1 1 one", "aspect"},
        BadComment{"version_text", "hisnegs format_version one", "format_version"},
        BadComment{"version_twice", "hisnegs format_version 1", "format_version appears twice"},
        BadComment{"no_key", "hisnegs", "comment 'hisnegs' without a key"}),
    [](const ::testing::TestParamInfo<BadComment>& info) { return std::string(info.param.name); });

// ----- refused saves -----

TEST(Checkpoint, SaveRefusesNonFiniteValuesAndWritesNothing) {
  ScratchDir dir;
  GaussianMixture m = random_mixture(4, 19);
  m[2].intensity_logit = std::numeric_limits<float>::infinity();
  try {
    save_checkpoint(dir / "out.ply", m, CheckpointMeta());
    ADD_FAILURE() << "saved a non-finite value";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("gaussian 2: intensity_logit is inf"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find((dir / "out.ply").string()), std::string::npos) << e.what();
  }
  m[2].intensity_logit = 0.0f;
  m[1].rotation = {0.0f, 0.0f, 0.0f, 0.0f};
  EXPECT_THROW(save_checkpoint(dir / "out.ply", m, CheckpointMeta()), std::invalid_argument);
  EXPECT_TRUE(dir.entries().empty());
}

TEST(Checkpoint, SaveRefusesMetadataItCouldNotReadBack) {
  ScratchDir dir;
  const GaussianMixture m = random_mixture(1, 20);
  const auto refuses = [&](const CheckpointMeta& meta) {
    EXPECT_THROW(save_checkpoint(dir / "out.ply", m, meta), std::invalid_argument);
  };
  CheckpointMeta meta;
  meta.extra = {{"volume_shape", "1 2 3"}};
  refuses(meta);
  meta.extra = {{"two words", "x"}};
  refuses(meta);
  meta.extra = {{"k", "line\nbreak"}};
  refuses(meta);
  meta = CheckpointMeta();
  meta.normalization = "a\nb";
  refuses(meta);
  meta = CheckpointMeta();
  meta.spacing_um = std::array<double, 3>{1.0, 0.0, 1.0};
  refuses(meta);
  meta = CheckpointMeta();
  meta.volume_shape_zyx = std::array<int, 3>{1, -1, 1};
  refuses(meta);
  meta = CheckpointMeta();
  meta.format_version = 2;
  refuses(meta);
  EXPECT_TRUE(dir.entries().empty());
}

TEST(GaussianMixture, DescribeNonFiniteNamesTheFirstValueAndItsGroup) {
  std::vector<float> g(3 * kGaussianParamCount, 0.5f);
  EXPECT_EQ(describe_non_finite<float>(g, "gradient"), "");
  g[kGaussianParamCount + 7] = std::numeric_limits<float>::quiet_NaN();  // Gaussian 1, rot_1
  g[2 * kGaussianParamCount + 0] = std::numeric_limits<float>::infinity();
  EXPECT_EQ(describe_non_finite<float>(g, "gradient"), "the rotation gradient of Gaussian 1 (nan)");
  g[kGaussianParamCount + 7] = 0.0f;
  EXPECT_EQ(describe_non_finite<float>(g, "gradient"), "the means gradient of Gaussian 2 (+inf)");
  g[2 * kGaussianParamCount] = 0.0f;
  g[4] = -std::numeric_limits<float>::infinity();
  EXPECT_EQ(describe_non_finite<float>(g, "gradient"), "the log-scales gradient of Gaussian 0 (-inf)");
  g[4] = 0.0f;
  g[10] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(describe_non_finite<float>(g, "gradient"), "the intensity gradient of Gaussian 0 (nan)");
}

}  // namespace
}  // namespace hisnegs::gmf

namespace hisnegs::gmf {
namespace {

gmf::BackgroundModel two_atoms(double top, double c) {
  gmf::BackgroundModel m;
  m.values = {0.0, top};
  m.cdf = {0.75, 1.0};
  m.samples_per_voxel = c;
  return m;
}

// A background by region survives the file; regions that do not match the stack, a
// missing or out-of-order region line, are refused naming the file.
TEST(Checkpoint, BackgroundByRegionRoundTripsAndBadLinesAreRefused) {
  ScratchDir dir;
  CheckpointMeta meta = full_meta();  // 512 x 512 x 60 voxels
  gmf::BackgroundField field;
  field.regions = gmf::BackgroundRegions::of({512, 512, 60}, 256);
  ASSERT_EQ(field.regions.count(), 4);
  field.merged = two_atoms(0.04, 0.7);
  field.models = {two_atoms(0.08, 0.7), gmf::BackgroundModel{{0.0}, {1.0}, 0.7, 10}, field.merged, two_atoms(0.02, 0.7)};
  set_background(meta, field);
  save_checkpoint(dir / "r.ply", random_mixture(3, 5), meta);
  const CheckpointMeta back = load_checkpoint(dir / "r.ply").meta;
  const gmf::BackgroundField read = background_field_of(back, "r.ply");
  EXPECT_EQ(read.regions, field.regions);
  EXPECT_EQ(read.merged, field.merged);
  ASSERT_EQ(read.models.size(), 4u);
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(read.models[i].values, field.models[i].values) << i;
    EXPECT_EQ(read.models[i].cdf, field.models[i].cdf) << i;
  }
  EXPECT_EQ(background_of(back, "r.ply"), field.merged);  // what a reader of one background sees
  // One region: no region lines at all.
  gmf::BackgroundField one;
  one.merged = field.merged;
  CheckpointMeta plain = full_meta();
  set_background(plain, one);
  EXPECT_FALSE(background_field_of(plain, "p.ply").regional());
  const auto refused = [&](const std::string& key, const std::string& value, const std::string& expected) {
    CheckpointMeta bad = meta;
    for (auto& [k, v] : bad.extra) {
      if (k == key) {
        v = value;
        break;
      }
    }
    try {
      (void)background_field_of(bad, "bad.ply");
      ADD_FAILURE() << key << " '" << value << "' was accepted";
    } catch (const io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("bad.ply"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  };
  refused("background_regions", "2 2", "background_regions");
  refused("background_regions", "9 1 1", "background_regions");
  refused("background_regions", "2 2 2", "8 regions declared, 4");
  refused("background_region", "1 " + field.models[0].text(), "background_region 0");
  refused("background_region", "0 1 2 3", "background");
}

}  // namespace
}  // namespace hisnegs::gmf
