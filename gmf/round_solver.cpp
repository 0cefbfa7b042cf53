// SPDX-License-Identifier: Apache-2.0
// The optimizer registry: gmf/optimizers.def, read twice (declarations, then the table).
#include "gmf/round_solver.hpp"

#include <algorithm>

namespace hisnegs::gmf {

#define HISNEGS_OPTIMIZER(name, function, description) RoundSolverOutcome function(const RoundSolverProblem&);
#include "gmf/optimizers.def"
#undef HISNEGS_OPTIMIZER

const std::vector<NamedSolver>& registered_optimizers() {
#define HISNEGS_OPTIMIZER(name, function, description) NamedSolver{name, description, &(function)},
  static const std::vector<NamedSolver> table = {
#include "gmf/optimizers.def"
  };
#undef HISNEGS_OPTIMIZER
  return table;
}

const NamedSolver* find_registered_optimizer(std::string_view name) {
  const auto& table = registered_optimizers();
  const auto it = std::find_if(table.begin(), table.end(), [&](const NamedSolver& s) { return s.name == name; });
  return it == table.end() ? nullptr : &*it;
}

std::string registered_optimizer_names() {
  std::string names;
  for (const NamedSolver& s : registered_optimizers()) names += (names.empty() ? "" : ", ") + s.name;
  return names;
}

}  // namespace hisnegs::gmf
