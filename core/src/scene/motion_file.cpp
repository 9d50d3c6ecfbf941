#include "muscle_deformation/core/scene/motion_file.hpp"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>

namespace muscle_deformation {
namespace {

std::string trimmed(const std::string& text) {
  const auto first = text.find_first_not_of(" \t\r\n");
  if (first == std::string::npos) return "";
  return text.substr(first, text.find_last_not_of(" \t\r\n") - first + 1);
}

std::string lowercase(std::string text) {
  std::transform(text.begin(), text.end(), text.begin(), [](unsigned char c) { return std::tolower(c); });
  return text;
}

std::vector<std::string> fieldsOf(const std::string& line) {
  std::vector<std::string> fields;
  std::istringstream stream(line);
  for (std::string field; stream >> field;) fields.push_back(field);
  return fields;
}

// A count the header states for the table (rows or columns), with the line that states it.
struct StatedCount {
  long value = 0;
  int line = 0;
};

}  // namespace

std::size_t MotionTable::columnIndex(const std::string& name) const {
  const auto found = std::find(column_names.begin(), column_names.end(), name);
  if (found == column_names.end()) throw std::invalid_argument(source + ": no column '" + name + "'");
  return static_cast<std::size_t>(found - column_names.begin());
}

bool MotionTable::hasColumn(const std::string& name) const {
  return std::find(column_names.begin(), column_names.end(), name) != column_names.end();
}

double MotionTable::value(std::size_t row, const std::string& column) const {
  const std::size_t index = columnIndex(column);
  if (row >= rowCount()) {
    throw std::out_of_range(source + ": row " + std::to_string(row) + " asked for, the table has " +
                            std::to_string(rowCount()));
  }
  return values(static_cast<Eigen::Index>(row), static_cast<Eigen::Index>(index));
}

MotionTable loadMotionFile(const std::string& path) {
  std::ifstream file(path);
  if (!file) throw SceneError(path + ": cannot open the motion file");
  const auto fail = [&](int line, const std::string& what) {
    throw SceneError(path + ":" + std::to_string(line) + ": " + what);
  };

  MotionTable table;
  table.source = path;
  std::optional<StatedCount> stated_rows, stated_columns;
  std::string line;
  int line_number = 0;
  bool header_ended = false;
  while (!header_ended && std::getline(file, line)) {
    ++line_number;
    const std::string text = trimmed(line);
    if (lowercase(text) == "endheader") {
      header_ended = true;
      break;
    }
    // OpenSim writes `key=value`, SIMM `key value`; other header lines are free text (a title, units, comments).
    std::string key, value;
    if (const auto equals = text.find('='); equals != std::string::npos) {
      key = lowercase(trimmed(text.substr(0, equals)));
      value = trimmed(text.substr(equals + 1));
    } else {
      const std::vector<std::string> fields = fieldsOf(text);
      if (fields.size() != 2) continue;
      key = lowercase(fields[0]);
      value = fields[1];
    }
    if (key == "indegrees") {
      const std::string answer = lowercase(value);
      if (answer != "yes" && answer != "no") fail(line_number, "inDegrees must be yes or no, not '" + value + "'");
      table.angles_in_degrees = answer == "yes";
      table.angle_unit_stated = true;
    } else if (key == "nrows" || key == "datarows" || key == "ncolumns" || key == "datacolumns") {
      char* end = nullptr;
      const long count = std::strtol(value.c_str(), &end, 10);
      if (value.empty() || *end != '\0' || count < 0) fail(line_number, key + " is not a count: '" + value + "'");
      auto& stated = (key == "nrows" || key == "datarows") ? stated_rows : stated_columns;
      if (stated && stated->value != count) {
        fail(line_number, key + " " + std::to_string(count) + " contradicts line " + std::to_string(stated->line) +
                              " (" + std::to_string(stated->value) + ")");
      }
      stated = StatedCount{count, line_number};
    }
  }
  if (!header_ended) throw SceneError(path + ": no endheader line (is it a .mot motion file?)");

  bool have_columns = false;
  std::vector<std::vector<double>> rows;
  while (std::getline(file, line)) {
    ++line_number;
    const std::vector<std::string> fields = fieldsOf(line);
    if (fields.empty()) continue;
    if (!have_columns) {
      if (lowercase(fields[0]) != "time") fail(line_number, "the column line must start with time");
      std::set<std::string> seen;
      for (std::size_t i = 1; i < fields.size(); ++i) {
        if (!seen.insert(fields[i]).second) fail(line_number, "column " + fields[i] + " appears twice");
        table.column_names.push_back(fields[i]);
      }
      have_columns = true;
      continue;
    }
    if (fields.size() != table.column_names.size() + 1) {
      fail(line_number, "expected " + std::to_string(table.column_names.size() + 1) + " fields, found " +
                            std::to_string(fields.size()));
    }
    std::vector<double> row(fields.size());
    for (std::size_t i = 0; i < fields.size(); ++i) {
      char* end = nullptr;
      errno = 0;
      row[i] = std::strtod(fields[i].c_str(), &end);
      if (*end != '\0' || errno == ERANGE || !std::isfinite(row[i])) {
        fail(line_number, "field " + std::to_string(i + 1) + " ('" + fields[i] + "') is not a finite number");
      }
    }
    if (!table.times_s.empty() && row[0] <= table.times_s.back()) fail(line_number, "time does not increase");
    table.times_s.push_back(row[0]);
    rows.push_back(std::move(row));
  }
  if (!have_columns) throw SceneError(path + ": no column line (time, ...) after endheader");
  if (rows.empty()) throw SceneError(path + ": no rows after the column line");
  if (stated_rows && static_cast<std::size_t>(stated_rows->value) != rows.size()) {
    fail(stated_rows->line, "the header states " + std::to_string(stated_rows->value) + " rows, the table has " +
                                std::to_string(rows.size()));
  }
  if (stated_columns && static_cast<std::size_t>(stated_columns->value) != table.column_names.size() + 1) {
    fail(stated_columns->line, "the header states " + std::to_string(stated_columns->value) +
                                   " columns, the table has " + std::to_string(table.column_names.size() + 1));
  }
  table.values.resize(static_cast<Eigen::Index>(rows.size()), static_cast<Eigen::Index>(table.column_names.size()));
  for (std::size_t r = 0; r < rows.size(); ++r) {
    for (std::size_t c = 0; c < table.column_names.size(); ++c) {
      table.values(static_cast<Eigen::Index>(r), static_cast<Eigen::Index>(c)) = rows[r][c + 1];
    }
  }
  return table;
}

}  // namespace muscle_deformation
