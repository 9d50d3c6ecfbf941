// Recorded motions in the OpenSim / SIMM motion format (.mot), e.g. the joint angles inverse kinematics wrote for a
// walking trial: a free-form header that ends with a line `endheader`, a line of column names starting with `time`,
// then one row of numbers per frame. Both header forms of the bundled trials are read: OpenSim's (`nRows=`,
// `nColumns=`, `inDegrees=yes`) and SIMM's (`datarows`, `datacolumns`); other header lines are free text.
#pragma once

#include "muscle_deformation/core/scene/skeleton.hpp"

#include <Eigen/Core>

#include <cstddef>
#include <string>
#include <vector>

namespace muscle_deformation {

struct MotionTable {
  std::string source;                     // the file it was read from
  std::vector<std::string> column_names;  // the data columns, after `time`
  std::vector<double> times_s;            // one per row, strictly increasing
  Eigen::MatrixXd values;                 // rows x column_names.size(), as written (angles in the file's unit)
  // Whether angles are written in degrees: the header's `inDegrees=yes|no` when it has one; without it degrees, the
  // unit of SIMM motion files and of OpenSim's inverse kinematics output (the bundled one-cycle trial has no such line
  // and is in degrees). angle_unit_stated says which of the two it was.
  bool angles_in_degrees = true;
  bool angle_unit_stated = false;

  std::size_t rowCount() const { return times_s.size(); }
  // Index of a column in column_names; throws std::invalid_argument naming the file and the column if there is none.
  std::size_t columnIndex(const std::string& name) const;
  bool hasColumn(const std::string& name) const;
  // values(row, columnIndex(name)); also throws std::out_of_range for a row past the end.
  double value(std::size_t row, const std::string& column) const;
};

// Reads a .mot file. Throws SceneError naming the file (and line) when it cannot be opened, has no `endheader` line,
// its column line does not start with `time` or repeats a name, a row has the wrong number of fields or a field that
// is not a finite number, times do not increase, there are no rows, the header's row or column count (nRows /
// datarows, nColumns / datacolumns, both counting the time column) disagrees with the table, or inDegrees is neither
// yes nor no.
MotionTable loadMotionFile(const std::string& path);

}  // namespace muscle_deformation
