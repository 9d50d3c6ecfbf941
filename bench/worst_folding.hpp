// The worst frame's fibre folding over a run (muscle_deformation::measureFibreFolding per frame): the most fibres
// folded and the largest tortuosity against rest, with their muscles, as the benches record them.
#pragma once

#include "bench_util.hpp"

#include "muscle_deformation/core/model/mass_spring_system.hpp"

#include <cmath>
#include <string>

namespace bench {

struct WorstFolding {
  int folded_fibres_max = 0;
  std::string most_folded_muscle;  // empty: no fibre folded
  double tortuosity_ratio_max = std::nan("");  // NaN: no frame measured
  std::string most_tortuous_muscle;

  void add(const muscle_deformation::MassSpringSystem& system, const muscle_deformation::FibreFolding& folding) {
    if (folding.folded_fibres > folded_fibres_max) {
      folded_fibres_max = folding.folded_fibres;
      most_folded_muscle = system.muscle_name[static_cast<std::size_t>(folding.most_folded_muscle)];
    }
    if (folding.worst_muscle >= 0 && !(folding.worst_tortuosity_ratio <= tortuosity_ratio_max)) {
      tortuosity_ratio_max = folding.worst_tortuosity_ratio;
      most_tortuous_muscle = system.muscle_name[static_cast<std::size_t>(folding.worst_muscle)];
    }
  }
  void measure(const muscle_deformation::MassSpringSystem& system, const Eigen::Matrix3Xd& position) {
    add(system, muscle_deformation::measureFibreFolding(system, position));
  }
  // The keys, each after `prefix`: folded_fibres_max, most_folded_muscle, fibre_tortuosity_ratio_max (null when not
  // measured), most_tortuous_muscle.
  void record(JsonRecords& records, const std::string& prefix = "") const {
    records.add(prefix + "folded_fibres_max", folded_fibres_max);
    records.add(prefix + "most_folded_muscle", most_folded_muscle);
    records.addMeasured(prefix + "fibre_tortuosity_ratio_max", tortuosity_ratio_max);
    records.add(prefix + "most_tortuous_muscle", most_tortuous_muscle);
  }
};

}  // namespace bench
