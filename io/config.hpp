// SPDX-License-Identifier: Apache-2.0
// Strict YAML configuration files: each top-level section is read into one
// `FooOptions` struct through its `visit(v)` (one `v("field", field)` call per
// field), so a field's name is written once. Unknown sections/keys and wrong
// types are InputErrors naming the file, line and key. Knows no option struct.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <initializer_list>
#include <memory>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

namespace hisnegs::io {

// Name <-> value table for enum fields, e.g. {{"exact", Mode::kExact}, ...}.
template <class E>
using EnumNames = std::initializer_list<std::pair<std::string_view, E>>;

class ConfigReader;

// A parsed YAML document (a map of sections, each a map of key: value).
class ConfigFile {
 public:
  // Throws InputError("PATH: ...") if the file is missing or not valid YAML, or
  // if its top level is not a map.
  static ConfigFile load(const std::filesystem::path& path);
  // `origin` names the text in error messages (a path or "<string>").
  static ConfigFile parse(const std::string& text, const std::string& origin);

  // Reads section `section` (absent = keep every default) into `options`.
  template <class Options>
  void read(std::string_view section, Options& options) const;

  // Throws InputError naming the first top-level key that is not in `known`.
  void check_sections(std::initializer_list<std::string_view> known) const;

  [[nodiscard]] const std::string& origin() const;

 private:
  struct Impl;
  std::shared_ptr<const Impl> impl_;
  friend class ConfigReader;
};

// Visitor that fills fields from one section and remembers which keys it used.
class ConfigReader {
 public:
  ConfigReader(const ConfigFile& file, std::string_view section);
  ~ConfigReader();
  ConfigReader(const ConfigReader&) = delete;
  ConfigReader& operator=(const ConfigReader&) = delete;

  void operator()(std::string_view key, double& value);
  void operator()(std::string_view key, int& value);
  void operator()(std::string_view key, std::int64_t& value);
  void operator()(std::string_view key, std::uint64_t& value);
  void operator()(std::string_view key, bool& value);
  void operator()(std::string_view key, std::string& value);
  void operator()(std::string_view key, std::array<double, 3>& value);
  void operator()(std::string_view key, std::vector<double>& value);
  // A number, or `auto` (no value: the option's documented automatic choice).
  void operator()(std::string_view key, std::optional<double>& value);
  template <class E>
  requires std::is_enum_v<E>
  void operator()(std::string_view key, E& value, EnumNames<E> names) {
    std::string text;
    if (!read_string(key, text)) return;
    for (const auto& [name, e] : names) {
      if (name == text) {
        value = e;
        return;
      }
    }
    std::string allowed;
    for (const auto& [name, e] : names) allowed += (allowed.empty() ? "" : "|") + std::string(name);
    fail(key, "expected one of " + allowed + ", got '" + text + "'");
  }

  // Throws InputError naming the first key of the section that no field read.
  void finish() const;

 private:
  bool read_string(std::string_view key, std::string& out);
  // The value of `key` (its text `text`) as a finite double, else fail naming what
  // else it may be (`alternatives`, e.g. " or auto").
  double number(std::string_view key, const std::string& text, std::string_view alternatives) const;
  [[noreturn]] void fail(std::string_view key, const std::string& message) const;
  struct State;
  std::unique_ptr<State> state_;
};

// Visitor that writes fields as YAML (the effective configuration of a run).
class ConfigWriter {
 public:
  void begin_section(std::string_view name);
  void blank_line() { out_ << "\n"; }
  template <class T>
  void operator()(std::string_view key, const T& value) {
    out_ << "  " << key << ": " << format(value) << "\n";
  }
  template <class E>
  requires std::is_enum_v<E>
  void operator()(std::string_view key, const E& value, EnumNames<E> names) {
    for (const auto& [name, e] : names) {
      if (e == value) out_ << "  " << key << ": " << name << "\n";
    }
  }
  [[nodiscard]] std::string str() const { return out_.str(); }

 private:
  static std::string format(double v);
  static std::string format(int v) { return std::to_string(v); }
  static std::string format(std::int64_t v) { return std::to_string(v); }
  static std::string format(std::uint64_t v) { return std::to_string(v); }
  static std::string format(bool v) { return v ? "true" : "false"; }
  static std::string format(const std::string& v);
  static std::string format(const std::array<double, 3>& v);
  static std::string format(const std::vector<double>& v);
  static std::string format(const std::optional<double>& v) { return v ? format(*v) : "auto"; }
  std::ostringstream out_;
};

template <class Options>
void ConfigFile::read(std::string_view section, Options& options) const {
  ConfigReader reader(*this, section);
  options.visit(reader);
  reader.finish();
}

[[noreturn]] void fail_enum(std::string_view option, std::string_view text, const std::string& allowed);

// Sets the enum field `key` of `options` from its config name `text` (e.g. a
// command-line override), using the names its visit() declares, so no name table
// is written twice. Throws InputError("OPTION = 'TEXT': expected one of a|b").
// Visitor behind set_enum_field: acts on the one enum field named `key`.
struct EnumFieldSetter {
  std::string_view key, text, option;
  bool found = false;
  template <class T>
  void operator()(std::string_view, T&) {}
  template <class E>
  requires std::is_enum_v<E>
  void operator()(std::string_view k, E& value, EnumNames<E> names) {
    if (k != key) return;
    found = true;
    std::string allowed;
    for (const auto& [name, e] : names) {
      if (name == text) {
        value = e;
        return;
      }
      allowed += (allowed.empty() ? "" : "|") + std::string(name);
    }
    fail_enum(option, text, allowed);
  }
};

template <class Options>
void set_enum_field(Options& options, std::string_view key, std::string_view text, std::string_view option) {
  EnumFieldSetter setter{key, text, option};
  options.visit(setter);
  if (!setter.found) throw std::logic_error("set_enum_field: no enum field '" + std::string(key) + "'");
}
// Validation helpers for `validate()`: throw InputError("SECTION.FIELD = VALUE: RULE").
[[noreturn]] void fail_option(std::string_view section, std::string_view field, const std::string& value,
                              std::string_view rule);
void require_in_range(std::string_view section, std::string_view field, double value, double lo, double hi);
void require_positive(std::string_view section, std::string_view field, double value);

}  // namespace hisnegs::io
