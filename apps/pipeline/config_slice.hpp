// SPDX-License-Identifier: Apache-2.0
// ConfigSlice: copies of the sections of an AppConfig a stage reads, named at
// compile time, and the YAML text of exactly those sections (what fingerprints
// the stage's settings). Knows no stage and no run folder.
#pragma once

#include <array>
#include <cstddef>
#include <stdexcept>
#include <string>
#include <tuple>
#include <type_traits>
#include <vector>

#include "apps/pipeline/app_config.hpp"
#include "io/config.hpp"

namespace hisnegs::apps {

namespace detail {

// The options type of section pointer `&AppConfig::name`; only those instantiate.
template <auto Member>
struct SectionType;
template <class Options, Options AppConfig::*Member>
struct SectionType<Member> {
  using type = Options;
};

// Whether two section pointers name the same section (pointers to members of
// different types never compare, so the types are checked first).
template <auto A, auto B>
constexpr bool same_section() {
  if constexpr (std::is_same_v<decltype(A), decltype(B)>) {
    return A == B;
  } else {
    return false;
  }
}

// How often section pointer `Member` occurs in `Members`.
template <auto Member, auto... Members>
constexpr int count_section() {
  return (0 + ... + static_cast<int>(same_section<Member, Members>()));
}

}  // namespace detail

// Holds copies of the sections `Members` (pointers to members of AppConfig, e.g.
// ConfigSlice<&AppConfig::volume, &AppConfig::gmf>). A stage function that takes a
// slice can read only those sections: get<&AppConfig::train>() on a slice without
// `train` does not compile. text() is the YAML of the held sections in AppConfig's
// file order, so a stage's fingerprint covers what it reads and nothing else.
template <auto... Members>
class ConfigSlice {
  static_assert(sizeof...(Members) > 0, "a slice holds at least one section");
  static_assert(((detail::count_section<Members, Members...>() == 1) && ...), "a slice names each section once");

 public:
  // Whether the slice holds section `Member`.
  template <auto Member>
  static constexpr bool kHolds = (detail::same_section<Member, Members>() || ...);

  explicit ConfigSlice(const AppConfig& config) : sections_(config.*Members...) {}
  explicit ConfigSlice(const typename detail::SectionType<Members>::type&... sections) : sections_(sections...) {}

  template <auto Member>
  requires kHolds<Member>
  [[nodiscard]] const typename detail::SectionType<Member>::type& get() const {
    return std::get<index_of<Member>()>(sections_);
  }

  // The slice of some of these sections (a stage handing part of its settings on).
  template <auto... Sub>
  requires(kHolds<Sub>&&...) [[nodiscard]] ConfigSlice<Sub...> slice() const {
    return ConfigSlice<Sub...>(get<Sub>()...);
  }

  // The config-file names of the held sections, in file order ("volume", "gmf").
  [[nodiscard]] static std::vector<std::string> section_names() {
    std::vector<std::string> names;
    AppConfig probe;  // only its member addresses are used, to map pointers to names
    probe.for_each_section([&](const char* name, auto& options) {
      if ((is_section<Members>(probe, options) || ...)) names.emplace_back(name);
    });
    return names;
  }

  // "volume:\n  channel: 0\n...": the held sections as YAML, in file order. Throws
  // std::logic_error if a member is not a section AppConfig::for_each_section visits.
  [[nodiscard]] std::string text() const {
    io::ConfigWriter writer;
    AppConfig probe;
    int written = 0;
    probe.for_each_section([&](const char* name, auto& options) {
      written += (static_cast<int>(write_if<Members>(writer, probe, name, options)) + ...);
    });
    if (written != static_cast<int>(sizeof...(Members))) {
      throw std::logic_error("ConfigSlice: a member is not a section of AppConfig::for_each_section");
    }
    return writer.str();
  }

 private:
  template <auto Member>
  static constexpr std::size_t index_of() {
    constexpr std::array<bool, sizeof...(Members)> match{detail::same_section<Member, Members>()...};
    for (std::size_t i = 0; i < match.size(); ++i) {
      if (match[i]) return i;
    }
    return match.size();
  }

  template <auto Member, class Options>
  static bool is_section(AppConfig& probe, Options& options) {
    if constexpr (std::is_same_v<typename detail::SectionType<Member>::type, Options>) {
      return &(probe.*Member) == &options;
    } else {
      return false;
    }
  }

  // Writes section `Member` if `options` is it; returns whether it was.
  template <auto Member, class Options>
  bool write_if(io::ConfigWriter& writer, AppConfig& probe, const char* name, Options& options) const {
    if (!is_section<Member>(probe, options)) return false;
    if constexpr (std::is_same_v<typename detail::SectionType<Member>::type, Options>) {
      writer.begin_section(name);
      Options copy = get<Member>();  // visit() is not const
      copy.visit(writer);
    }
    return true;
  }

  std::tuple<typename detail::SectionType<Members>::type...> sections_;
};

}  // namespace hisnegs::apps
