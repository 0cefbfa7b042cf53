// SPDX-License-Identifier: Apache-2.0
// PLY 1.0 reading (ascii, binary either endianness) and writing (binary little
// endian, atomic) of PlyTable, plus PlyElement's non-template members.
// Knows nothing of what the elements mean (see gmf/core/checkpoint.cpp).
#include "io/ply.hpp"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <system_error>

#include "io/atomic_file.hpp"
#include "io/error.hpp"

namespace hisnegs::io {
namespace fs = std::filesystem;

// ----- types -----

namespace {
struct TypeName {
  std::string_view name;
  PlyType type;
};
constexpr TypeName kTypeNames[] = {
    {"char", PlyType::kInt8},       {"uchar", PlyType::kUint8},    {"short", PlyType::kInt16},
    {"ushort", PlyType::kUint16},   {"int", PlyType::kInt32},      {"uint", PlyType::kUint32},
    {"float", PlyType::kFloat32},   {"double", PlyType::kFloat64}, {"int8", PlyType::kInt8},
    {"uint8", PlyType::kUint8},     {"int16", PlyType::kInt16},    {"uint16", PlyType::kUint16},
    {"int32", PlyType::kInt32},     {"uint32", PlyType::kUint32},  {"float32", PlyType::kFloat32},
    {"float64", PlyType::kFloat64},
};
}  // namespace

std::string_view to_string(PlyType type) {
  for (const TypeName& t : kTypeNames) {
    if (t.type == type) return t.name;  // the classic names come first
  }
  throw std::logic_error("invalid PlyType");
}

std::size_t size_of(PlyType type) {
  return detail::visit_ply_type(type, [](auto tag) { return sizeof(tag); });
}

std::optional<PlyType> parse_ply_type(std::string_view name) {
  for (const TypeName& t : kTypeNames) {
    if (t.name == name) return t.type;
  }
  return std::nullopt;
}

// ----- PlyElement -----

namespace {
// Names go into a whitespace-separated header, so they must be one printable token.
bool is_valid_name(std::string_view name) {
  if (name.empty()) return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    const auto u = static_cast<unsigned char>(c);
    return u > 0x20 && u != 0x7f;
  });
}
}  // namespace

PlyElement::PlyElement(std::string name) : name_(std::move(name)) {}

PlyElement::PlyElement(std::string name, std::int64_t count, std::vector<PlyProperty> properties, Uninitialized)
    : name_(std::move(name)), count_(count), properties_(std::move(properties)) {
  if (count_ < 0) {
    throw std::invalid_argument("PLY element '" + name_ + "': negative count " + std::to_string(count_));
  }
  offsets_.reserve(properties_.size());
  for (std::size_t i = 0; i < properties_.size(); ++i) {
    const PlyProperty& p = properties_[i];
    if (p.name.empty()) throw std::invalid_argument("PLY element '" + name_ + "': empty property name");
    for (std::size_t j = 0; j < i; ++j) {
      if (properties_[j].name == p.name) {
        throw std::invalid_argument("PLY element '" + name_ + "': duplicate property '" + p.name + "'");
      }
    }
    offsets_.push_back(row_size_);
    row_size_ += size_of(p.type);
  }
  if (row_size_ > 0 && static_cast<std::uint64_t>(count_) > std::numeric_limits<std::size_t>::max() / row_size_) {
    throw std::invalid_argument("PLY element '" + name_ + "': " + std::to_string(count_) + " rows of " +
                                std::to_string(row_size_) + " bytes overflow");
  }
  bytes_.resize(static_cast<std::size_t>(count_) * row_size_);  // left uninitialized
}

PlyElement::PlyElement(std::string name, std::int64_t count, std::vector<PlyProperty> properties)
    : PlyElement(std::move(name), count, std::move(properties), Uninitialized{}) {
  std::fill(bytes_.begin(), bytes_.end(), std::byte{0});
}

std::optional<std::size_t> PlyElement::find_property(std::string_view name) const {
  for (std::size_t i = 0; i < properties_.size(); ++i) {
    if (properties_[i].name == name) return i;
  }
  return std::nullopt;
}

std::size_t PlyElement::require_property(std::string_view name) const {
  if (const auto i = find_property(name)) return *i;
  throw std::out_of_range("PLY element '" + name_ + "' has no property '" + std::string(name) + "'");
}

void PlyElement::require_index(std::size_t prop) const {
  if (prop >= properties_.size()) {
    throw std::out_of_range("PLY element '" + name_ + "' has no property #" + std::to_string(prop) + " (it has " +
                            std::to_string(properties_.size()) + ")");
  }
}

void PlyElement::throw_unrepresentable(std::size_t prop, std::int64_t row, double value,
                                       const std::string& target) const {
  char buf[64];
  const auto res = std::to_chars(buf, buf + sizeof buf, value);
  throw std::range_error("PLY element '" + name_ + "' row " + std::to_string(row) + " property '" +
                         properties_[prop].name + "': value " + std::string(buf, res.ptr) +
                         " is not representable as " + target);
}

double PlyElement::value(std::int64_t row, std::size_t prop) const {
  require_index(prop);
  if (row < 0 || row >= count_) {
    throw std::out_of_range("PLY element '" + name_ + "' has no row " + std::to_string(row) + " (it has " +
                            std::to_string(count_) + ")");
  }
  const std::byte* p = bytes_.data() + static_cast<std::size_t>(row) * row_size_ + offsets_[prop];
  return detail::visit_ply_type(properties_[prop].type, [p](auto tag) {
    decltype(tag) v;
    std::memcpy(&v, p, sizeof v);
    return static_cast<double>(v);
  });
}

PlyElement PlyElement::with_property(std::string name, PlyType type, std::int64_t count_if_first) const {
  if (!is_valid_name(name)) {
    throw std::invalid_argument("PLY element '" + name_ + "': invalid property name '" + name + "'");
  }
  std::vector<PlyProperty> props = properties_;
  props.push_back({std::move(name), type});
  PlyElement next(name_, properties_.empty() ? count_if_first : count_, std::move(props));
  if (row_size_ > 0) {
    for (std::int64_t r = 0; r < count_; ++r) {
      std::memcpy(next.bytes_.data() + static_cast<std::size_t>(r) * next.row_size_,
                  bytes_.data() + static_cast<std::size_t>(r) * row_size_, row_size_);
    }
  }
  return next;
}

// ----- PlyTable -----

const PlyElement* PlyTable::find(std::string_view name) const {
  for (const PlyElement& e : elements) {
    if (e.name() == name) return &e;
  }
  return nullptr;
}

PlyElement* PlyTable::find(std::string_view name) {
  for (PlyElement& e : elements) {
    if (e.name() == name) return &e;
  }
  return nullptr;
}

// ----- reading -----

namespace {

constexpr std::size_t kMaxHeaderLineBytes = 64 * 1024;
constexpr std::size_t kMaxHeaderBytes = 16 * 1024 * 1024;

enum class Format { kAscii, kBinaryLittleEndian, kBinaryBigEndian };

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};
using FilePtr = std::unique_ptr<std::FILE, FileCloser>;

// A header line for a one-line message: control bytes replaced, long lines cut.
std::string quote(std::string_view line) { return "'" + printable(line, 120) + "'"; }

std::vector<std::string_view> split_ws(std::string_view s) {
  std::vector<std::string_view> out;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    const std::size_t start = i;
    while (i < s.size() && !std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    if (i > start) out.push_back(s.substr(start, i - start));
  }
  return out;
}

// Text after a "comment" / "obj_info" keyword and one separating blank, verbatim.
std::string rest_after_keyword(std::string_view line, std::string_view keyword) {
  std::string_view rest = line.substr(keyword.size());
  if (!rest.empty()) rest.remove_prefix(1);
  return std::string(rest);
}

bool starts_with_keyword(std::string_view line, std::string_view keyword) {
  return line.starts_with(keyword) &&
         (line.size() == keyword.size() || line[keyword.size()] == ' ' || line[keyword.size()] == '\t');
}

struct PendingElement {
  std::string name;
  std::int64_t count = 0;
  std::vector<PlyProperty> properties;
  std::size_t row_size = 0;
};

void byteswap_in_place(PlyElement& element) {
  // An element without rows has no buffer: base would be null, and null plus an
  // offset is undefined behaviour.
  if (element.count() == 0) return;
  std::byte* base = element.bytes().data();
  const std::size_t stride = element.row_size();
  for (std::size_t p = 0; p < element.properties().size(); ++p) {
    const std::size_t size = size_of(element.properties()[p].type);
    if (size == 1) continue;
    std::byte* q = base + element.offset(p);
    for (std::int64_t r = 0; r < element.count(); ++r, q += stride) std::reverse(q, q + size);
  }
}

// Whitespace-separated tokens of the ascii body, tracking line numbers.
class Tokenizer {
 public:
  Tokenizer(std::string_view text, int first_line) : text_(text), line_(first_line) {}
  // The next token, or empty at the end of the text.
  std::string_view next() {
    while (pos_ < text_.size() && std::isspace(static_cast<unsigned char>(text_[pos_]))) {
      if (text_[pos_] == '\n') ++line_;
      ++pos_;
    }
    const std::size_t start = pos_;
    while (pos_ < text_.size() && !std::isspace(static_cast<unsigned char>(text_[pos_]))) ++pos_;
    return text_.substr(start, pos_ - start);
  }
  [[nodiscard]] int line() const { return line_; }
  [[nodiscard]] std::size_t remaining() const { return text_.size() - pos_; }

 private:
  std::string_view text_;
  std::size_t pos_ = 0;
  int line_;
};

template <class S>
bool parse_ascii_value(std::string_view token, S& out) {
  if (token.size() > 1 && token[0] == '+' && token[1] != '-') token.remove_prefix(1);
  const char* end = token.data() + token.size();
  if constexpr (std::is_floating_point_v<S>) {
    const auto res = std::from_chars(token.data(), end, out);
    if (res.ptr != end) return false;
    if (res.ec == std::errc::result_out_of_range) {
      // Underflow ("1e-50" in a float column) rounds to 0 or a denormal, as any
      // reader does; overflow ("1e39") stays an error.
      const std::string copy(token);
      char* stop = nullptr;
      const long double v = std::strtold(copy.c_str(), &stop);
      if (stop != copy.c_str() + copy.size() || !(std::abs(v) <= std::numeric_limits<S>::max())) return false;
      out = static_cast<S>(v);
      return true;
    }
    return res.ec == std::errc{};
  } else {
    std::int64_t v = 0;
    const auto res = std::from_chars(token.data(), end, v);
    if (res.ec != std::errc{} || res.ptr != end || !std::in_range<S>(v)) return false;
    out = static_cast<S>(v);
    return true;
  }
}

}  // namespace

// Owns the open file while read_ply walks it; friend of PlyElement so rows can be
// allocated without zero-filling them first.
class PlyReader {
 public:
  explicit PlyReader(const fs::path& path) : path_(path) {}

  PlyTable read() {
    const int fd = open_regular_file(path_);  // never blocks on a FIFO swapped in
    file_.reset(::fdopen(fd, "rb"));
    if (!file_) {
      ::close(fd);
      fail(std::string("cannot open: ") + std::strerror(errno));
    }
    struct stat st {};
    if (::fstat(fd, &st) != 0) fail(std::string("cannot get file size: ") + std::strerror(errno));
    file_size_ = static_cast<std::uintmax_t>(st.st_size);
    read_header();
    if (format_ == Format::kAscii) {
      read_ascii_body();
    } else {
      read_binary_body();
    }
    return std::move(table_);
  }

 private:
  [[noreturn]] void fail(const std::string& message) const { fail_input(path_, message); }
  [[noreturn]] void fail_line(const std::string& problem) const {
    fail("header line " + std::to_string(line_no_) + ": " + problem + " in " + quote(line_));
  }

  // Reads the next header line into line_ (without "\n" / "\r\n"); false at EOF.
  bool next_line() {
    line_.clear();
    int c = 0;
    bool any = false;
    while ((c = std::getc(file_.get())) != EOF) {
      any = true;
      ++header_bytes_;
      if (c == '\n') break;
      line_.push_back(static_cast<char>(c));
      if (line_.size() > kMaxHeaderLineBytes) {
        fail("header line " + std::to_string(line_no_ + 1) + " is longer than " + std::to_string(kMaxHeaderLineBytes) +
             " bytes (not a PLY header?)");
      }
    }
    if (header_bytes_ > kMaxHeaderBytes) {
      fail("header is longer than " + std::to_string(kMaxHeaderBytes) + " bytes without end_header");
    }
    if (!line_.empty() && line_.back() == '\r') line_.pop_back();
    if (any) ++line_no_;
    return any;
  }

  void read_header() {
    read_magic();
    line_no_ = 1;
    bool have_format = false;
    bool ended = false;
    while (!ended && next_line()) {
      const std::vector<std::string_view> tok = split_ws(line_);
      if (tok.empty()) fail_line("empty header line");
      require_printable_line();  // after this, names and comments quoted in messages are printable
      const std::string_view key = tok[0];
      if (key == "format") {
        if (have_format) fail_line("second format line");
        parse_format_line(tok);
        have_format = true;
      } else if (starts_with_keyword(line_, "comment")) {
        table_.comments.push_back(rest_after_keyword(line_, "comment"));
      } else if (starts_with_keyword(line_, "obj_info")) {
        table_.obj_info.push_back(rest_after_keyword(line_, "obj_info"));
      } else if (key == "element") {
        parse_element_line(tok);
      } else if (key == "property") {
        parse_property_line(tok);
      } else if (key == "end_header") {
        if (tok.size() != 1) fail_line("malformed end_header line");
        ended = true;
      } else {
        fail_line("malformed header line (unknown keyword '" + std::string(key) + "')");
      }
    }
    if (!ended) fail("header ends without end_header after line " + std::to_string(line_no_));
    if (!have_format) fail("header has no format line");
    const long pos = std::ftell(file_.get());
    if (pos < 0) fail(std::string("cannot tell the header size: ") + std::strerror(errno));
    data_offset_ = static_cast<std::uint64_t>(pos);
  }

  // The magic first: a binary non-PLY file must not be scanned for newlines.
  void read_magic() {
    char magic[5] = {};
    const std::size_t got = std::fread(magic, 1, 4, file_.get());
    const std::string_view m(magic, got);
    if (!(m == "ply\n" || m == "ply\r" || (got == 3 && m == "ply"))) {
      fail("not a PLY file (the first line is not 'ply')");
    }
    if (m == "ply\r" && std::getc(file_.get()) != '\n') {
      fail("not a PLY file (the first line is not 'ply')");
    }
  }

  void require_printable_line() const {
    if (std::any_of(line_.begin(), line_.end(), [](char c) {
          const auto u = static_cast<unsigned char>(c);
          return (u < 0x20 && c != '\t') || u == 0x7f;
        })) {
      fail_line("control character");
    }
  }

  // "format TYPE 1.0"
  void parse_format_line(const std::vector<std::string_view>& tok) {
    if (tok.size() != 3) fail_line("malformed format line (expected 'format TYPE 1.0')");
    if (tok[1] == "ascii") {
      format_ = Format::kAscii;
    } else if (tok[1] == "binary_little_endian") {
      format_ = Format::kBinaryLittleEndian;
    } else if (tok[1] == "binary_big_endian") {
      format_ = Format::kBinaryBigEndian;
    } else {
      fail_line("unknown format '" + std::string(tok[1]) +
                "' (expected ascii, binary_little_endian or binary_big_endian)");
    }
    if (tok[2] != "1.0") fail_line("unsupported PLY version '" + std::string(tok[2]) + "' (expected 1.0)");
  }

  // "element NAME COUNT"
  void parse_element_line(const std::vector<std::string_view>& tok) {
    if (tok.size() != 3) fail_line("malformed element line (expected 'element NAME COUNT')");
    PendingElement e;
    e.name = std::string(tok[1]);
    for (const PendingElement& other : pending_) {
      if (other.name == e.name) fail_line("duplicate element '" + e.name + "'");
    }
    const char* end = tok[2].data() + tok[2].size();
    const auto res = std::from_chars(tok[2].data(), end, e.count);
    if (res.ec != std::errc{} || res.ptr != end || e.count < 0) {
      fail_line("element count '" + std::string(tok[2]) + "' is not a number in [0, 2^63)");
    }
    pending_.push_back(std::move(e));
  }

  // "property TYPE NAME" of the last element (lists are refused).
  void parse_property_line(const std::vector<std::string_view>& tok) {
    if (pending_.empty()) fail_line("property before any element");
    PendingElement& e = pending_.back();
    if (tok.size() >= 2 && tok[1] == "list") {
      const std::string name = tok.size() >= 5 ? std::string(tok.back()) : std::string("?");
      fail("list properties are not supported: element " + e.name + " property " + name + " (header line " +
           std::to_string(line_no_) + ")");
    }
    if (tok.size() != 3) fail_line("malformed property line (expected 'property TYPE NAME')");
    const std::optional<PlyType> type = parse_ply_type(tok[1]);
    if (!type) fail_line("unknown property type '" + std::string(tok[1]) + "'");
    for (const PlyProperty& p : e.properties) {
      if (p.name == tok[2]) fail_line("duplicate property '" + p.name + "' in element " + e.name);
    }
    e.properties.push_back({std::string(tok[2]), *type});
    e.row_size += size_of(*type);
  }

  void read_binary_body() {
    std::uint64_t remaining = file_size_ > data_offset_ ? file_size_ - data_offset_ : 0;
    for (PendingElement& e : pending_) {
      // Size check before allocating: a header claiming 4e9 rows fails here.
      const auto count = static_cast<std::uint64_t>(e.count);
      const bool too_big = e.row_size > 0 && count > remaining / e.row_size;
      if (too_big) {
        // count × row_size may not fit 64 bits; say so rather than print a wrapped number.
        const bool overflows = count > std::numeric_limits<std::uint64_t>::max() / e.row_size;
        const std::string expected = overflows
                                         ? std::to_string(count) + " rows × " + std::to_string(e.row_size) + " bytes"
                                         : std::to_string(count * e.row_size) + " bytes";
        fail("expected " + expected + " of " + e.name + " data, file has " + std::to_string(remaining));
      }
      PlyElement element(std::move(e.name), e.count, std::move(e.properties), PlyElement::Uninitialized{});
      const std::size_t want = element.bytes().size();
      const std::size_t got = want ? std::fread(element.bytes().data(), 1, want, file_.get()) : 0;
      if (got != want) {  // the file shrank under us, or a read error
        fail("expected " + std::to_string(want) + " bytes of " + element.name() + " data, could read " +
             std::to_string(got));
      }
      remaining -= want;
      if (format_ == Format::kBinaryBigEndian) byteswap_in_place(element);
      table_.elements.push_back(std::move(element));
    }
    if (remaining > 0) {
      fail(std::to_string(remaining) + " unexpected bytes after the last element (" +
           (table_.elements.empty() ? std::string("no elements") : table_.elements.back().name()) + ")");
    }
  }

  void read_ascii_body() {
    const std::uint64_t remaining = file_size_ > data_offset_ ? file_size_ - data_offset_ : 0;
    std::string text(static_cast<std::size_t>(remaining), '\0');
    const std::size_t got = remaining ? std::fread(text.data(), 1, text.size(), file_.get()) : 0;
    text.resize(got);
    Tokenizer tokens(text, line_no_ + 1);
    for (PendingElement& e : pending_) {
      // Every value takes at least one character and one separator.
      const std::uint64_t per_row = e.properties.size();
      if (per_row > 0 && static_cast<std::uint64_t>(e.count) > (tokens.remaining() + 1) / 2 / per_row) {
        fail("expected " + std::to_string(e.count) + " rows of " + std::to_string(per_row) + " values of " + e.name +
             " data, file has only " + std::to_string(tokens.remaining()) + " bytes left");
      }
      PlyElement element(std::move(e.name), e.count, std::move(e.properties), PlyElement::Uninitialized{});
      std::byte* row = element.bytes().data();
      const std::int64_t rows = element.properties().empty() ? 0 : element.count();
      for (std::int64_t r = 0; r < rows; ++r, row += element.row_size()) {
        for (std::size_t p = 0; p < element.properties().size(); ++p) {
          const std::string_view token = tokens.next();
          const PlyProperty& prop = element.properties()[p];
          if (token.empty()) {
            fail("ascii data cut short: expected " + std::to_string(element.count()) + " rows of " + element.name() +
                 ", file ends in row " + std::to_string(r) + " at property " + prop.name);
          }
          detail::visit_ply_type(prop.type, [&](auto tag) {
            using S = decltype(tag);
            S v{};
            if (!parse_ascii_value(token, v)) {
              fail("line " + std::to_string(tokens.line()) + ": " + quote(token) + " is not a valid " +
                   std::string(to_string(prop.type)) + " for " + element.name() + " " + std::to_string(r) +
                   " property " + prop.name);
            }
            std::memcpy(row + element.offset(p), &v, sizeof v);
          });
        }
      }
      table_.elements.push_back(std::move(element));
    }
    const std::string_view extra = tokens.next();
    if (!extra.empty()) {
      fail("line " + std::to_string(tokens.line()) + ": unexpected data " + quote(extra) + " after the last element");
    }
  }

  const fs::path& path_;
  FilePtr file_;
  std::uint64_t file_size_ = 0;
  Format format_ = Format::kAscii;
  std::string line_;
  int line_no_ = 0;
  std::uint64_t header_bytes_ = 0;  // bytes consumed by next_line()
  std::uint64_t data_offset_ = 0;
  std::vector<PendingElement> pending_;
  PlyTable table_;
};

PlyTable read_ply(const fs::path& path) { return PlyReader(path).read(); }

// ----- writing -----

namespace {
void check_header_text(std::string_view what, const std::string& text) {
  if (text.find_first_of("\r\n") != std::string::npos) {
    throw std::invalid_argument("PLY " + std::string(what) + " contains a line break: " + quote(text));
  }
}
}  // namespace

namespace {

// What the header says of one element.
struct ElementHeader {
  const std::string& name;
  std::int64_t count;
  const std::vector<PlyProperty>& properties;
};

// The binary_little_endian header; std::invalid_argument for a bad name or a
// comment with a line break.
std::string binary_header(const std::vector<std::string>& comments, const std::vector<std::string>& obj_info,
                          std::span<const ElementHeader> elements) {
  std::string header = "ply\nformat binary_little_endian 1.0\n";
  for (const std::string& c : comments) {
    check_header_text("comment", c);
    header += c.empty() ? "comment\n" : "comment " + c + "\n";
  }
  for (const std::string& o : obj_info) {
    check_header_text("obj_info", o);
    header += o.empty() ? "obj_info\n" : "obj_info " + o + "\n";
  }
  for (const ElementHeader& e : elements) {
    if (!is_valid_name(e.name)) throw std::invalid_argument("invalid PLY element name " + quote(e.name));
    header += "element " + e.name + " " + std::to_string(e.count) + "\n";
    for (const PlyProperty& p : e.properties) {
      if (!is_valid_name(p.name)) {
        throw std::invalid_argument("PLY element '" + e.name + "': invalid property name " + quote(p.name));
      }
      header += "property " + std::string(to_string(p.type)) + " " + p.name + "\n";
    }
  }
  header += "end_header\n";
  return header;
}

// A temporary file beside `path` being written, renamed into place by commit().
class BinaryOutput {
 public:
  explicit BinaryOutput(const fs::path& path) : out_(path), file_(std::fopen(out_.temp_path().c_str(), "wb")) {
    if (!file_) fail_input(path, std::string("cannot open for writing: ") + std::strerror(errno));
  }
  void write(const void* data, std::size_t size) {
    if (size && std::fwrite(data, 1, size, file_.get()) != size) fail_write(out_.target(), errno);
  }
  void commit() {
    if (std::fflush(file_.get()) != 0) fail_write(out_.target(), errno);
    if (std::fclose(file_.release()) != 0) fail_write(out_.target(), errno);
    out_.commit();
  }

 private:
  AtomicFile out_;
  FilePtr file_;
};

}  // namespace

void write_ply(const fs::path& path, const PlyTable& table) {
  // The header is checked while the temporary exists: a bad table still leaves
  // nothing behind (AtomicFile removes the temporary on the way out).
  BinaryOutput out(path);
  std::vector<ElementHeader> elements;
  for (const PlyElement& e : table.elements) elements.push_back({e.name(), e.count(), e.properties()});
  const std::string header = binary_header(table.comments, table.obj_info, elements);
  out.write(header.data(), header.size());
  for (const PlyElement& e : table.elements) out.write(e.bytes().data(), e.bytes().size());
  out.commit();
}

struct PlyRowWriter::State {
  BinaryOutput out;
  std::size_t row_size = 0;
  std::int64_t expected = 0, written = 0;
  explicit State(const fs::path& path) : out(path) {}
};

PlyRowWriter::PlyRowWriter(const fs::path& path, const std::vector<std::string>& comments, const std::string& element,
                           std::int64_t count, const std::vector<PlyProperty>& properties)
    : state_(std::make_unique<State>(path)) {
  if (count < 0) throw std::invalid_argument("PLY element '" + element + "': negative count");
  for (const PlyProperty& p : properties) state_->row_size += size_of(p.type);
  state_->expected = count;
  const ElementHeader e{element, count, properties};
  const std::string header = binary_header(comments, {}, std::span<const ElementHeader>(&e, 1));
  state_->out.write(header.data(), header.size());
}

PlyRowWriter::~PlyRowWriter() = default;

void PlyRowWriter::append(std::span<const std::byte> bytes) {
  if (state_->row_size == 0 || bytes.size() % state_->row_size != 0) {
    throw std::logic_error("PlyRowWriter::append: not whole rows");
  }
  const auto rows = static_cast<std::int64_t>(bytes.size() / state_->row_size);
  if (state_->written + rows > state_->expected) {
    throw std::logic_error("PlyRowWriter::append: more rows than the header says");
  }
  state_->out.write(bytes.data(), bytes.size());
  state_->written += rows;
}

void PlyRowWriter::commit() {
  if (state_->written != state_->expected) {
    throw std::logic_error("PlyRowWriter::commit: " + std::to_string(state_->written) + " rows of " +
                           std::to_string(state_->expected));
  }
  state_->out.commit();
}

}  // namespace hisnegs::io
