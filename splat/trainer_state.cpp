// SPDX-License-Identifier: Apache-2.0
// Trainer::serialize_state and Trainer::restore_state: the optimizer state beside a
// checkpoint (step, Adam moments, density statistics, RNG, options) as a binary
// record (io/binary_io.hpp) tied to its parameters by a hash.
#include <array>
#include <cstring>
#include <sstream>

#include "io/binary_io.hpp"
#include "io/hash.hpp"
#include "splat/trainer.hpp"

namespace hisnegs::splat {
namespace {

constexpr char kStateMagic[8] = {'H', 'N', 'G', 'T', 'R', 'N', 'S', '1'};

// "name=value" lines of every train option (doubles with 17 digits, so equal text = equal value).
std::string options_text(TrainOptions options) {
  std::ostringstream s;
  s.precision(17);
  options.visit([&](std::string_view name, const auto& value, auto&&...) { s << name << '=' << value << '\n'; });
  return s.str();
}

std::uint64_t params_hash(std::span<const float> params) { return io::fnv1a64(params.data(), params.size_bytes()); }

}  // namespace

std::string Trainer::serialize_state() const {
  io::BinaryWriter w;
  w.put(kStateMagic);
  w.put<std::int32_t>(epoch_);
  w.put<std::int64_t>(adam_.steps());
  w.put<std::uint64_t>(params_.size() / gmf::kGaussianParamCount);
  w.put<std::uint64_t>(params_hash(params_));
  adam_.write_moments(w);
  w.put_array(std::span<const double>(grad_accum_));
  w.put_array(std::span<const std::uint32_t>(grad_count_));
  std::ostringstream rng;
  rng << rng_;
  w.put_string(rng.str());
  w.put_string(options_text(options_));
  return w.take();
}

void Trainer::restore_state(std::string_view bytes, std::vector<float> params, const std::string& source) {
  io::BinaryReader r(bytes, source, "training state");
  const auto magic = r.get<std::array<char, 8>>();
  if (std::memcmp(magic.data(), kStateMagic, 8) != 0) r.fail("not a hisnegs training state file");
  const auto epoch = r.get<std::int32_t>();
  const auto step = r.get<std::int64_t>();
  const auto K = r.get<std::uint64_t>();
  const auto hash = r.get<std::uint64_t>();
  if (K * gmf::kGaussianParamCount != params.size()) {
    r.fail("written for " + std::to_string(K) + " Gaussians, the checkpoint has " +
           std::to_string(params.size() / gmf::kGaussianParamCount));
  }
  if (hash != params_hash(params)) r.fail("the checkpoint's parameters are not the ones this state was saved with");
  if (epoch < 0 || step < 0) r.fail("negative epoch or step");
  gmf::Adam<float> adam(adam_.options());
  adam.read_moments(r, step, K);
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
  params_ = std::move(params);
  adam_ = std::move(adam);
  grad_accum_ = std::move(accum);
  grad_count_ = std::move(count);
  rng_ = rng;
  epoch_ = epoch;
}

}  // namespace hisnegs::splat
