// SPDX-License-Identifier: Apache-2.0
// Markdown/CSV tables and the machine description of the report commands.
#include "apps/pipeline/report_tables.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <thread>

#include "apps/pipeline/format.hpp"
#include "splat/backend.hpp"

namespace hisnegs::apps {

void Table::add(std::vector<std::string> row) {
  if (row.size() != header.size()) throw std::logic_error("Table::add: row width differs from the header");
  rows.push_back(std::move(row));
}

std::string Table::markdown() const {
  auto line = [](const std::vector<std::string>& cells) {
    std::string s = "|";
    for (const std::string& c : cells) s += " " + c + " |";
    return s + "\n";
  };
  std::string s = line(header) + "|";
  for (std::size_t i = 0; i < header.size(); ++i) s += i == 0 ? "---|" : "---:|";
  s += "\n";
  for (const auto& r : rows) s += line(r);
  return s;
}

std::string Table::csv() const {
  auto cell = [](const std::string& c) {
    if (c.find_first_of(",\"\n") == std::string::npos) return c;
    std::string q = "\"";
    for (char ch : c) q += ch == '"' ? std::string("\"\"") : std::string(1, ch);
    return q + "\"";
  };
  auto line = [&](const std::vector<std::string>& cells) {
    std::string s;
    for (std::size_t i = 0; i < cells.size(); ++i) s += (i ? "," : "") + cell(cells[i]);
    return s + "\n";
  };
  std::string s = line(header);
  for (const auto& r : rows) s += line(r);
  return s;
}

namespace {

// The value after "KEY<spaces>:" of the first line of `file` starting with KEY.
std::string proc_field(const char* file, const std::string& key) {
  std::ifstream in(file);
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(key, 0) != 0) continue;
    const auto colon = line.find(':');
    if (colon == std::string::npos) continue;
    const auto start = line.find_first_not_of(" \t", colon + 1);
    return start == std::string::npos ? std::string() : line.substr(start);
  }
  return {};
}

}  // namespace

std::string machine_description() {
  std::string cpu = proc_field("/proc/cpuinfo", "model name");
  if (cpu.empty()) cpu = "unknown CPU";
  const unsigned threads = std::thread::hardware_concurrency();
  const std::string mem_kb = proc_field("/proc/meminfo", "MemTotal");
  std::string s = cpu + " (" + std::to_string(threads) + " logical CPUs)";
  if (!mem_kb.empty()) s += ", " + format_bytes(std::stod(mem_kb) * 1024.0) + " RAM";
  const splat::CudaDeviceInfo& gpu = splat::cuda_device_info();
  if (gpu.available) {
    s += strf("; GPU: %s (compute %d.%d, %s)", gpu.name.c_str(), gpu.compute_major, gpu.compute_minor,
              format_bytes(static_cast<double>(gpu.memory_bytes)).c_str());
  } else {
    s += std::string("; GPU: none") + (gpu.compiled ? "" : " (built without CUDA)");
  }
  return s;
}

double file_bytes(const std::string& path) {
  std::error_code ec;
  const auto n = std::filesystem::file_size(path, ec);
  return ec ? 0.0 : static_cast<double>(n);
}

double median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const std::size_t n = values.size();
  return n % 2 ? values[n / 2] : 0.5 * (values[n / 2 - 1] + values[n / 2]);
}

Table frame_time_table(std::vector<double> seconds) {
  Table t{{"metric", "value"}, {}};
  if (seconds.empty()) return t;
  std::sort(seconds.begin(), seconds.end());
  const double n = static_cast<double>(seconds.size());
  double sum = 0, sq = 0;
  for (double s : seconds) sum += s;
  const double mean = sum / n;
  for (double s : seconds) sq += (s - mean) * (s - mean);
  const std::size_t m = seconds.size();
  t.add({"frames", std::to_string(m)});
  t.add({"mean frame time", strf("%.2f ms", 1e3 * mean)});
  t.add({"median frame time", strf("%.2f ms", 1e3 * median(seconds))});
  t.add({"best frame time", strf("%.2f ms", 1e3 * seconds.front())});
  t.add({"worst frame time", strf("%.2f ms", 1e3 * seconds.back())});
  t.add({"standard deviation", strf("%.2f ms", 1e3 * std::sqrt(sq / n))});
  t.add({"mean FPS", strf("%.1f", 1.0 / mean)});
  t.add({"all frames > 30 FPS?", seconds.back() < 1.0 / 30.0 ? "yes" : "no"});
  return t;
}

Table gaussian_table(const std::vector<std::pair<std::string, gmf::MixtureStats>>& models) {
  Table t{{"property"}, {}};
  for (const auto& [label, st] : models) t.header.push_back(label);
  auto row = [&](const std::string& name, auto cell) {
    std::vector<std::string> r{name};
    for (const auto& m : models) r.push_back(cell(m.second));
    t.add(std::move(r));
  };
  row("Number of Gaussians K", [](const gmf::MixtureStats& s) { return std::to_string(s.count); });
  row("Memory footprint (K x 11 float32)", [](const gmf::MixtureStats& s) {
    return strf("%.3f MB", static_cast<double>(s.count * gmf::kGaussianParamCount * 4) / 1e6);
  });
  row("Mean scale (x, y, z)", [](const gmf::MixtureStats& s) {
    return strf("(%.4f, %.4f, %.4f)", s.mean_scale[0], s.mean_scale[1], s.mean_scale[2]);
  });
  row("Intensity range",
      [](const gmf::MixtureStats& s) { return strf("[%.3f, %.3f]", s.intensity_min, s.intensity_max); });
  row("Mean intensity", [](const gmf::MixtureStats& s) { return strf("%.3f", s.intensity_mean); });
  return t;
}

Table memory_table(const MemoryInputs& in) {
  Table t{{"representation", "parameters", "memory", "compression"}, {}};
  const double voxels = static_cast<double>(in.shape_xyz[0]) * in.shape_xyz[1] * in.shape_xyz[2];
  const double raw = 4.0 * voxels;
  auto ratio = [&](double bytes) { return bytes > 0 ? strf("%.1fx", raw / bytes) : std::string("-"); };
  t.add({strf("Raw volume %dx%dx%d (float32)", in.shape_xyz[0], in.shape_xyz[1], in.shape_xyz[2]), strf("%.0f", voxels),
         format_bytes(raw), "1x"});
  if (in.sparse_file) {
    t.add({"Sparse grid file " + in.sparse_file->first, "-", format_bytes(in.sparse_file->second),
           ratio(in.sparse_file->second)});
  }
  const double params = static_cast<double>(in.gaussians * gmf::kGaussianParamCount);
  t.add({strf("Gaussian mixture (K = %zu, 11 float32 each)", in.gaussians), strf("%.0f", params),
         format_bytes(4.0 * params), ratio(4.0 * params)});
  if (in.checkpoint_file) {
    t.add({"Checkpoint file " + in.checkpoint_file->first, "-", format_bytes(in.checkpoint_file->second),
           ratio(in.checkpoint_file->second)});
  }
  return t;
}

}  // namespace hisnegs::apps
