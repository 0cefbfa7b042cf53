// SPDX-License-Identifier: Apache-2.0
// Tests of io/config: typed reads, unknown keys/sections, type errors with
// file:line, enum names, and that the writer's YAML reads back identically.
#include "io/config.hpp"

#include <gtest/gtest.h>

#include "io/error.hpp"
#include "io/memory_limit.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {

enum class Mode { kA, kB };

struct Demo {
  int n = 1;
  double x = 0.5;
  bool flag = false;
  std::string name = "abc";
  std::array<double, 3> v{1, 2, 3};
  std::vector<double> list;
  std::uint64_t seed = 0;
  Mode mode = Mode::kA;
  std::optional<double> amount;  // unset = auto
  template <class V>
  void visit(V&& vis) {
    vis("n", n);
    vis("x", x);
    vis("flag", flag);
    vis("name", name);
    vis("v", v);
    vis("list", list);
    vis("seed", seed);
    vis("mode", mode, EnumNames<Mode>{{"a", Mode::kA}, {"b", Mode::kB}});
    vis("amount", amount);
  }
};

std::string error_of(const std::string& yaml) {
  try {
    Demo d;
    ConfigFile::parse(yaml, "cfg.yaml").read("demo", d);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(Config, ReadsEveryTypeAndKeepsDefaults) {
  Demo d;
  ConfigFile::parse(
      "demo:\n  n: 7\n  x: 3e-3\n  flag: true\n  v: [4, 5, 6.5]\n  list: []\n  seed: 18446744073709551615\n  mode: b\n",
      "cfg.yaml")
      .read("demo", d);
  EXPECT_EQ(d.n, 7);
  EXPECT_DOUBLE_EQ(d.x, 3e-3);
  EXPECT_TRUE(d.flag);
  EXPECT_EQ(d.name, "abc");  // absent: default kept
  EXPECT_EQ(d.v, (std::array<double, 3>{4, 5, 6.5}));
  EXPECT_TRUE(d.list.empty());
  EXPECT_EQ(d.seed, 18446744073709551615ull);
  EXPECT_EQ(d.mode, Mode::kB);
}

TEST(Config, AbsentSectionKeepsDefaults) {
  Demo d;
  ConfigFile::parse("other: {}\n", "cfg.yaml").read("demo", d);
  EXPECT_EQ(d.n, 1);
}

TEST(Config, UnknownKeyNamesFileLineAndSuggests) {
  const std::string e = error_of("demo:\n  n: 2\n  nmae: x\n");
  EXPECT_NE(e.find("cfg.yaml:3"), std::string::npos) << e;
  EXPECT_NE(e.find("unknown key 'demo.nmae'"), std::string::npos) << e;
  EXPECT_NE(e.find("did you mean 'name'"), std::string::npos) << e;
}

TEST(Config, WrongTypesAreErrorsNamingTheKey) {
  EXPECT_NE(error_of("demo:\n  n: 1.5\n").find("demo.n: expected an integer, got '1.5'"), std::string::npos);
  EXPECT_NE(error_of("demo:\n  x: abc\n").find("demo.x: expected a number"), std::string::npos);
  EXPECT_NE(error_of("demo:\n  x: .nan\n").find("finite"), std::string::npos);
  EXPECT_NE(error_of("demo:\n  flag: 1\n").find("expected true or false"), std::string::npos);
  EXPECT_NE(error_of("demo:\n  v: [1, 2]\n").find("exactly 3"), std::string::npos);
  EXPECT_NE(error_of("demo:\n  n: [1, 2]\n").find("expected a single value"), std::string::npos);
  EXPECT_NE(error_of("demo:\n  mode: c\n").find("expected one of a|b, got 'c'"), std::string::npos);
  EXPECT_NE(error_of("demo:\n  seed: -1\n").find("non-negative"), std::string::npos);
  EXPECT_NE(error_of("demo: 5\n").find("must be a map"), std::string::npos);
  EXPECT_NE(error_of("demo: [\n").find("invalid YAML"), std::string::npos);
}

TEST(Config, UnknownSectionIsAnError) {
  const ConfigFile f = ConfigFile::parse("demo: {}\ncamrea: {}\n", "cfg.yaml");
  try {
    f.check_sections({"demo", "camera"});
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("unknown section 'camrea' (did you mean 'camera'?)"), std::string::npos)
        << e.what();
  }
}

// Found by fuzzing (fuzz_config): YAML allows lists and maps as keys; reading
// their name threw YAML::TypedBadConversion instead of an InputError.
TEST(Config, ListOrMapAsKeyIsAnInputError) {
  EXPECT_THROW(ConfigFile::parse("? [a, b]\n: 1\n", "cfg.yaml").check_sections({"demo"}), InputError);
  const std::string e = error_of("demo:\n  ? {n: 1}\n  : 2\n");
  EXPECT_NE(e.find("cfg.yaml:2: a key name must be a word"), std::string::npos) << e;
}

// Found by fuzzing (fuzz_config): the file's text quoted in a message (a key, a
// value, yaml-cpp's message on a bad escape) carried its line breaks and control bytes.
TEST(Config, MessagesQuotingTheFileStayOneLine) {
  const std::string bad_escape(" [1, \b\0\n", 8);
  const std::vector<std::string> cases = {
      "demo:\n  n: \"1\\n2\"\n",  // a value with a line break
      "demo:\n  \"a\\rb\": 1\n",  // an unknown key with a carriage return
      "\"x\\ny\": 1\n",           // an unknown section with a line break
      "(\xb1\r\r\r\r\r:",         // the fuzzer's input: a section name ending in CRs
      bad_escape,                 // the fuzzer's input: invalid YAML quoting a control byte
  };
  for (const std::string& yaml : cases) {
    try {
      Demo d;
      const ConfigFile file = ConfigFile::parse(yaml, "cfg.yaml");
      file.check_sections({"demo"});
      file.read("demo", d);
      ADD_FAILURE() << "accepted: " << yaml;
    } catch (const InputError& e) {
      EXPECT_EQ(std::string(e.what()).find_first_of("\r\n"), std::string::npos) << e.what();
    }
  }
}

TEST(Config, WriterOutputReadsBackIdentically) {
  Demo d;
  d.n = -3;
  d.x = 0.1234567891;
  d.flag = true;
  d.name = "hello world";
  d.v = {0.5, -1e-7, 3};
  d.list = {1, 2};
  d.seed = 42;
  d.mode = Mode::kB;
  d.amount = 0.75;
  ConfigWriter w;
  w.begin_section("demo");
  d.visit(w);
  Demo back;
  ConfigFile::parse(w.str(), "dump").read("demo", back);
  EXPECT_EQ(back.amount, d.amount);
  Demo automatic;
  ConfigWriter wa;
  wa.begin_section("demo");
  automatic.visit(wa);
  EXPECT_NE(wa.str().find("  amount: auto\n"), std::string::npos) << wa.str();
  Demo back_auto;
  back_auto.amount = 1.0;
  ConfigFile::parse(wa.str(), "dump").read("demo", back_auto);
  EXPECT_FALSE(back_auto.amount.has_value());
  EXPECT_EQ(back.n, d.n);
  EXPECT_DOUBLE_EQ(back.x, d.x);
  EXPECT_EQ(back.flag, d.flag);
  EXPECT_EQ(back.name, d.name);
  EXPECT_EQ(back.v, d.v);
  EXPECT_EQ(back.list, d.list);
  EXPECT_EQ(back.seed, d.seed);
  EXPECT_EQ(back.mode, d.mode);
}

TEST(Config, RangeHelpersNameSectionFieldAndValue) {
  try {
    require_in_range("camera", "width", 3, 8, 100);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()), "camera.width = 3: must be in [8, 100]");
  }
  EXPECT_THROW(require_positive("a", "b", 0.0), InputError);
  EXPECT_NO_THROW(require_positive("a", "b", 1e-9));
}

TEST(MemorySize, ParsesBinaryAndDecimalUnitsAndAuto) {
  EXPECT_EQ(parse_memory_size("auto", "gmf.max_memory"), std::nullopt);
  EXPECT_EQ(*parse_memory_size("1GiB", "f"), 1073741824.0);
  EXPECT_EQ(*parse_memory_size("1G", "f"), 1073741824.0);
  EXPECT_EQ(*parse_memory_size("1.5 GB", "f"), 1.5e9);
  EXPECT_EQ(*parse_memory_size("512MiB", "f"), 512.0 * 1048576.0);
  EXPECT_EQ(*parse_memory_size("4096", "f"), 4096.0);
  EXPECT_GT(physical_memory_bytes(), 0.0);
}

// A Slurm job's --mem or a container's limit is a cgroup limit: below the
// machine's RAM, and what MemAvailable does not show. A fake /proc and /sys tree.
TEST(MemorySize, TheTightestCgroupLimitCountsWhereverItIsSet) {
  testing::ScratchDir dir;
  namespace fs = std::filesystem;
  const auto put = [&](const std::string& file, const std::string& text) {
    fs::create_directories((dir / file).parent_path());
    testing::write_text(dir / file, text);
  };
  // v2: the job's own level sets nothing, its parent 4 GiB with 1 GiB used, the
  // root nothing ("max").
  put("proc_v2", "0::/slurm/job_7/step_0\n");
  put("sys/cgroup.controllers", "cpu memory\n");
  put("sys/memory.max", "max\n");
  put("sys/slurm/job_7/memory.max", "4294967296\n");
  put("sys/slurm/job_7/memory.current", "1073741824\n");
  put("sys/slurm/job_7/step_0/memory.max", "max\n");
  put("sys/slurm/job_7/step_0/memory.current", "5\n");
  std::optional<CgroupMemory> m = cgroup_memory(dir / "proc_v2", dir / "sys");
  ASSERT_TRUE(m.has_value());
  EXPECT_EQ(m->limit, 4294967296.0);
  EXPECT_EQ(m->headroom, 3221225472.0);
  // v1 inside a container: the host's path does not exist under the mount, so
  // the mount's root holds the limit; "no limit" is 2^63 rounded to a page.
  put("proc_v1", "4:memory:/host/path\n0::/\n");
  put("sys1/memory/memory.limit_in_bytes", "2147483648\n");
  put("sys1/memory/memory.usage_in_bytes", "1073741824\n");
  m = cgroup_memory(dir / "proc_v1", dir / "sys1");
  ASSERT_TRUE(m.has_value());
  EXPECT_EQ(m->headroom, 1073741824.0);
  put("sys2/memory/memory.limit_in_bytes", "9223372036854771712\n");
  EXPECT_FALSE(cgroup_memory(dir / "proc_v1", dir / "sys2").has_value());
  EXPECT_FALSE(cgroup_memory(dir / "missing", dir / "sys").has_value());
  // This machine: what may be used is never more than the RAM.
  EXPECT_GT(usable_memory_bytes(), 0.0);
  EXPECT_LE(usable_memory_bytes(), physical_memory_bytes());
}

TEST(MemorySize, RefusesWhatIsNotASizeNamingTheField) {
  for (const char* bad : {"", "lots", "1 parsec", "-1G", "0", "GiB", "1e400G", "1..2G"}) {
    try {
      (void)parse_memory_size(bad, "gmf.max_memory");
      ADD_FAILURE() << "accepted '" << bad << "'";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("gmf.max_memory = '"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace hisnegs::io
