// SPDX-License-Identifier: Apache-2.0
// How hisnegs knows it was launched on several MPI ranks (apps/pipeline/distributed.hpp):
// from the variables Open MPI's mpirun, PMI launchers and Slurm's srun set; a Slurm
// batch script alone (no job step) is one process.
#include "apps/pipeline/distributed.hpp"

#include <gtest/gtest.h>

#include "tests/test_support.hpp"

namespace hisnegs::apps {
namespace {

TEST(Distributed, TheLauncherSaysHowManyRanks) {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "SLURM_STEP_ID", "SLURM_STEP_NUM_TASKS"}) {
    ASSERT_EQ(std::getenv(name), nullptr) << name << " is set: this test must run outside a launcher";
  }
  EXPECT_EQ(launched_ranks(), 1);
  {
    const testing::ScopedEnv ompi("OMPI_COMM_WORLD_SIZE", "4");
    EXPECT_EQ(launched_ranks(), 4);
  }
  {
    const testing::ScopedEnv pmi("PMI_SIZE", "3");
    EXPECT_EQ(launched_ranks(), 3);
  }
  {
    const testing::ScopedEnv tasks("SLURM_STEP_NUM_TASKS", "8");
    EXPECT_EQ(launched_ranks(), 1) << "a batch script has no job step";
    const testing::ScopedEnv step("SLURM_STEP_ID", "0");
    EXPECT_EQ(launched_ranks(), 8);
  }
  for (const char* bad : {"", "0", "-2", "x", "2x"}) {
    const testing::ScopedEnv ompi("OMPI_COMM_WORLD_SIZE", bad);
    EXPECT_EQ(launched_ranks(), 1) << "'" << bad << "'";
  }
  // This process alone: a job of one rank whose operations do nothing.
  const Job& alone = job();
  EXPECT_EQ(alone.size(), 1);
  EXPECT_TRUE(alone.root());
  EXPECT_EQ(rank_prefix(alone), "");
  float values[2] = {1.0f, -3.0f};
  alone.max_to_root(values);
  EXPECT_EQ(values[1], -3.0f);
}

}  // namespace
}  // namespace hisnegs::apps
