// SPDX-License-Identifier: Apache-2.0
// yaml-cpp behind ConfigFile/ConfigReader: typed reads with file:line messages,
// unknown-key detection with a "did you mean" hint, YAML writing of values.
#include "io/config.hpp"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>
#include <iomanip>
#include <limits>
#include <optional>
#include <set>
#include <sstream>

#include "io/atomic_file.hpp"
#include "io/error.hpp"

namespace hisnegs::io {

struct ConfigFile::Impl {
  YAML::Node root;
  std::string origin;
};

namespace {

std::size_t edit_distance(std::string_view a, std::string_view b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diag = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] != b[j - 1])});
      diag = up;
    }
  }
  return row[b.size()];
}

// " (did you mean 'beta'?)" when a known name is within 2 edits.
std::string suggestion(std::string_view key, const std::set<std::string, std::less<>>& known) {
  std::string best;
  std::size_t best_d = 3;
  for (const auto& k : known) {
    const std::size_t d = edit_distance(key, k);
    if (d < best_d) {
      best_d = d;
      best = k;
    }
  }
  return best.empty() ? "" : " (did you mean '" + best + "'?)";
}

std::string at_line(const std::string& origin, const YAML::Node& node) {
  const YAML::Mark m = node.Mark();
  if (m.line < 0) return origin;
  return origin + ":" + std::to_string(m.line + 1);
}

// The text of a map key; YAML also allows lists and maps as keys ("? [a, b]"),
// which name no section or field. `what` is "section" or "key".
std::string key_text(const std::string& origin, const YAML::Node& key, const char* what) {
  if (!key.IsScalar()) {
    throw InputError(at_line(origin, key) + ": a " + what + " name must be a word, got a list or map");
  }
  return key.Scalar();
}

// yaml-cpp keeps the first of two equal keys and drops the second without a word;
// a config must not say two things, so a repeated key anywhere is an error.
// Nesting and size are bounded (a config is two levels and a few hundred nodes):
// an alias inside its own anchor makes the node graph cyclic, aliases of aliases
// expand exponentially ("billion laughs"), and deep nesting would exhaust the stack.
void reject_duplicate_keys(const std::string& origin, const YAML::Node& node, int depth, long& visited) {
  constexpr int kMaxDepth = 32;
  constexpr long kMaxNodes = 100000;
  if (depth > kMaxDepth) {
    throw InputError(at_line(origin, node) + ": nested more than " + std::to_string(kMaxDepth) +
                     " levels deep (or an alias inside its own anchor)");
  }
  if (++visited > kMaxNodes) {
    throw InputError(origin + ": more than " + std::to_string(kMaxNodes) +
                     " YAML nodes once aliases are expanded; a config is far smaller");
  }
  if (node.IsMap()) {
    std::set<std::string> seen;
    for (const auto& kv : node) {
      if (kv.first.IsScalar() && !seen.insert(kv.first.Scalar()).second) {
        throw InputError(at_line(origin, kv.first) + ": duplicate key '" + printable(kv.first.Scalar(), 80) +
                         "' (each key may appear once)");
      }
      reject_duplicate_keys(origin, kv.second, depth + 1, visited);
    }
  } else if (node.IsSequence()) {
    for (const auto& item : node) reject_duplicate_keys(origin, item, depth + 1, visited);
  }
}

}  // namespace

ConfigFile ConfigFile::parse(const std::string& text, const std::string& origin) {
  auto impl = std::make_shared<Impl>();
  impl->origin = origin;
  try {
    // A second document ('---' after content) would be ignored by YAML::Load.
    // (Found by text: YAML::LoadAll loops forever on some malformed input.)
    std::istringstream lines(text);
    bool content = false;
    int number = 0;
    for (std::string line; std::getline(lines, line);) {
      ++number;
      const bool marker = line.rfind("---", 0) == 0 && (line.size() == 3 || line[3] == ' ' || line[3] == '\r');
      if (marker && content) {
        throw InputError(origin + ":" + std::to_string(number) +
                         ": a second YAML document ('---'); a config is one document");
      }
      const std::size_t first = line.find_first_not_of(" \t\r");
      if (!marker && first != std::string::npos && line[first] != '#') content = true;
    }
    impl->root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw InputError(origin + ":" + std::to_string(e.mark.line + 1) + ": invalid YAML: " + printable(e.msg));
  }
  long visited = 0;
  reject_duplicate_keys(origin, impl->root, 0, visited);
  if (impl->root.IsNull()) impl->root = YAML::Node(YAML::NodeType::Map);
  if (!impl->root.IsMap()) throw InputError(origin + ": expected a map of sections at the top level");
  ConfigFile f;
  f.impl_ = std::move(impl);
  return f;
}

ConfigFile ConfigFile::load(const std::filesystem::path& path) { return parse(read_file(path), path.string()); }

const std::string& ConfigFile::origin() const { return impl_->origin; }

void ConfigFile::check_sections(std::initializer_list<std::string_view> known) const {
  std::set<std::string, std::less<>> names(known.begin(), known.end());
  for (const auto& kv : impl_->root) {
    const std::string key = key_text(impl_->origin, kv.first, "section");
    if (!names.count(key)) {
      throw InputError(at_line(impl_->origin, kv.first) + ": unknown section '" + printable(key) + "'" +
                       suggestion(key, names));
    }
  }
}

struct ConfigReader::State {
  std::string origin;
  std::string section;
  YAML::Node node;  // the section's map (or null when absent)
  std::set<std::string, std::less<>> used;
};

ConfigReader::ConfigReader(const ConfigFile& file, std::string_view section) : state_(std::make_unique<State>()) {
  state_->origin = file.impl_->origin;
  state_->section = std::string(section);
  const YAML::Node node = file.impl_->root[state_->section];
  if (node && !node.IsNull()) {
    if (!node.IsMap()) {
      throw InputError(at_line(state_->origin, node) + ": section '" + state_->section +
                       "' must be a map of key: value");
    }
    state_->node = node;
  }
}

ConfigReader::~ConfigReader() = default;

void ConfigReader::fail(std::string_view key, const std::string& message) const {
  const YAML::Node n = state_->node ? state_->node[std::string(key)] : YAML::Node();
  // `message` may quote the file's text: printable() keeps it one line.
  throw InputError((n ? at_line(state_->origin, n) : state_->origin) + ": " + state_->section + "." + std::string(key) +
                   ": " + printable(message));
}

namespace {
// The scalar text of node, or nullopt when it is not a scalar.
std::optional<std::string> scalar_text(const YAML::Node& n) {
  if (!n.IsScalar()) return std::nullopt;
  return n.Scalar();
}
}  // namespace

bool ConfigReader::read_string(std::string_view key, std::string& out) {
  state_->used.insert(std::string(key));
  if (!state_->node) return false;
  const YAML::Node n = state_->node[std::string(key)];
  if (!n) return false;
  const auto text = scalar_text(n);
  if (!text) fail(key, "expected a single value, got a list or map");
  out = *text;
  return true;
}

void ConfigReader::operator()(std::string_view key, std::string& value) { read_string(key, value); }

double ConfigReader::number(std::string_view key, const std::string& text, std::string_view alternatives) const {
  double v = 0;
  try {
    v = state_->node[std::string(key)].as<double>();
  } catch (const YAML::Exception&) {
    fail(key, "expected a number" + std::string(alternatives) + ", got '" + text + "'");
  }
  if (!std::isfinite(v)) fail(key, "expected a finite number" + std::string(alternatives) + ", got '" + text + "'");
  return v;
}

void ConfigReader::operator()(std::string_view key, double& value) {
  std::string text;
  if (read_string(key, text)) value = number(key, text, "");
}

void ConfigReader::operator()(std::string_view key, std::optional<double>& value) {
  std::string text;
  if (!read_string(key, text)) return;
  if (text == "auto") {
    value.reset();
  } else {
    value = number(key, text, " or auto");
  }
}

namespace {
template <class Int>
bool parse_integer(const std::string& text, Int& out) {
  std::size_t pos = 0;
  try {
    if constexpr (std::is_unsigned_v<Int>) {
      if (!text.empty() && text[0] == '-') return false;
      const unsigned long long v = std::stoull(text, &pos, 10);
      if (v > std::numeric_limits<Int>::max()) return false;
      out = static_cast<Int>(v);
    } else {
      const long long v = std::stoll(text, &pos, 10);
      if (v < std::numeric_limits<Int>::min() || v > std::numeric_limits<Int>::max()) return false;
      out = static_cast<Int>(v);
    }
  } catch (const std::exception&) {
    return false;
  }
  return pos == text.size();
}
}  // namespace

void ConfigReader::operator()(std::string_view key, int& value) {
  std::string text;
  if (read_string(key, text) && !parse_integer(text, value)) fail(key, "expected an integer, got '" + text + "'");
}
void ConfigReader::operator()(std::string_view key, std::int64_t& value) {
  std::string text;
  if (read_string(key, text) && !parse_integer(text, value)) fail(key, "expected an integer, got '" + text + "'");
}
void ConfigReader::operator()(std::string_view key, std::uint64_t& value) {
  std::string text;
  if (read_string(key, text) && !parse_integer(text, value)) {
    fail(key, "expected a non-negative integer, got '" + text + "'");
  }
}

void ConfigReader::operator()(std::string_view key, bool& value) {
  std::string text;
  if (!read_string(key, text)) return;
  if (text == "true") {
    value = true;
  } else if (text == "false") {
    value = false;
  } else {
    fail(key, "expected true or false, got '" + text + "'");
  }
}

void ConfigReader::operator()(std::string_view key, std::vector<double>& value) {
  state_->used.insert(std::string(key));
  if (!state_->node) return;
  const YAML::Node n = state_->node[std::string(key)];
  if (!n) return;
  if (!n.IsSequence()) fail(key, "expected a list of numbers like [1, 2, 3]");
  std::vector<double> out;
  for (const auto& item : n) {
    double v = 0;
    try {
      v = item.as<double>();
    } catch (const YAML::Exception&) {
      fail(key, "expected a list of numbers, got element '" + (item.IsScalar() ? item.Scalar() : "?") + "'");
    }
    if (!std::isfinite(v)) fail(key, "list elements must be finite");
    out.push_back(v);
  }
  value = std::move(out);
}

void ConfigReader::operator()(std::string_view key, std::array<double, 3>& value) {
  std::vector<double> v(value.begin(), value.end());
  (*this)(key, v);
  if (v.size() != 3) fail(key, "expected exactly 3 numbers, got " + std::to_string(v.size()));
  std::copy(v.begin(), v.end(), value.begin());
}

void ConfigReader::finish() const {
  if (!state_->node) return;
  for (const auto& kv : state_->node) {
    const std::string key = key_text(state_->origin, kv.first, "key");
    if (!state_->used.count(key)) {
      throw InputError(at_line(state_->origin, kv.first) + ": unknown key '" + state_->section + "." + printable(key) +
                       "'" + suggestion(key, state_->used));
    }
  }
}

void ConfigWriter::begin_section(std::string_view name) { out_ << name << ":\n"; }

std::string ConfigWriter::format(double v) {
  // Shortest text that reads back to the same double (0.003, not 0.0030000000000000001).
  char buf[64];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}
std::string ConfigWriter::format(const std::string& v) {
  std::string out = "\"";
  for (char c : v) {
    if (c == '"' || c == '\\') out += '\\';
    out += c;
  }
  return out + "\"";
}
std::string ConfigWriter::format(const std::array<double, 3>& v) {
  return format(std::vector<double>(v.begin(), v.end()));
}
std::string ConfigWriter::format(const std::vector<double>& v) {
  std::ostringstream s;
  s << "[";
  for (std::size_t i = 0; i < v.size(); ++i) s << (i ? ", " : "") << format(v[i]);
  s << "]";
  return s.str();
}

void fail_enum(std::string_view option, std::string_view text, const std::string& allowed) {
  throw InputError(std::string(option) + " = '" + std::string(text) + "': expected one of " + allowed);
}

void fail_option(std::string_view section, std::string_view field, const std::string& value, std::string_view rule) {
  throw InputError(std::string(section) + "." + std::string(field) + " = " + value + ": " + std::string(rule));
}

void require_in_range(std::string_view section, std::string_view field, double value, double lo, double hi) {
  if (!(value >= lo && value <= hi)) {
    std::ostringstream r, v;
    r << "must be in [" << lo << ", " << hi << "]";
    v << value;
    fail_option(section, field, v.str(), r.str());
  }
}

void require_positive(std::string_view section, std::string_view field, double value) {
  if (!(value > 0.0) || !std::isfinite(value)) {
    std::ostringstream v;
    v << value;
    fail_option(section, field, v.str(), "must be a positive finite number");
  }
}

}  // namespace hisnegs::io
