// Small helpers shared by the benchmark programs: command line, medians, JSON output, machine description.
#pragma once

#include <algorithm>
#include <ctime>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <cmath>
#include <filesystem>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

namespace bench {

struct Options {
  std::string out_dir = "out/bench";
  bool quick = false;  // fewer repetitions, for smoke runs
};

inline Options parseOptions(int argc, char** argv) {
  Options options;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--out" && i + 1 < argc) {
      options.out_dir = argv[++i];
    } else if (arg == "--quick") {
      options.quick = true;
    } else {
      std::cerr << "usage: " << argv[0] << " [--out DIR] [--quick]\n";
      std::exit(2);
    }
  }
  // The output directory is made (or refused) before the run, not after minutes of measuring.
  std::error_code error;
  std::filesystem::create_directories(options.out_dir, error);
  if (error || !std::filesystem::is_directory(options.out_dir)) {
    std::cerr << argv[0] << ": cannot make the output directory " << options.out_dir
              << (error ? ": " + error.message() : std::string(": not a directory")) << "\n";
    std::exit(2);
  }
  return options;
}

inline double median(std::vector<double> values) {
  if (values.empty()) return 0;
  std::sort(values.begin(), values.end());
  const std::size_t mid = values.size() / 2;
  return values.size() % 2 ? values[mid] : 0.5 * (values[mid - 1] + values[mid]);
}

// CPU time of the calling thread: on a shared machine it leaves out the time the thread waited for a core, which
// wall time counts. Benchmarks report both.
inline double threadCpuMilliseconds() {
  timespec now{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &now);
  return 1e3 * static_cast<double>(now.tv_sec) + 1e-6 * static_cast<double>(now.tv_nsec);
}

template <class Function>
double cpuMillisecondsOf(Function&& function) {
  const double start = threadCpuMilliseconds();
  function();
  return threadCpuMilliseconds() - start;
}

template <class Function>
double millisecondsOf(Function&& function) {
  const auto start = std::chrono::steady_clock::now();
  function();
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
}

// A JSON list of flat objects, written as one file.
class JsonRecords {
 public:
  void begin() { fields_.clear(); }
  void add(const std::string& key, double value) {
    std::ostringstream text;
    text.precision(6);
    text << value;
    fields_.push_back("\"" + key + "\": " + text.str());
  }
  void add(const std::string& key, const std::string& value) { fields_.push_back("\"" + key + "\": \"" + value + "\""); }
  // A figure that may not have been measured: null when absent or not finite (never 0).
  void addMeasured(const std::string& key, const std::optional<double>& value) {
    if (value && std::isfinite(*value))
      add(key, *value);
    else
      fields_.push_back("\"" + key + "\": null");
  }
  void end() {
    std::string object = "  {";
    for (std::size_t i = 0; i < fields_.size(); ++i) object += (i ? ", " : "") + fields_[i];
    records_.push_back(object + "}");
  }
  bool write(const std::string& path) const {
    std::ofstream file(path);
    if (!file) return false;
    file << "[\n";
    for (std::size_t i = 0; i < records_.size(); ++i) file << records_[i] << (i + 1 < records_.size() ? ",\n" : "\n");
    file << "]\n";
    return static_cast<bool>(file);
  }

 private:
  std::vector<std::string> fields_;
  std::vector<std::string> records_;
};

// The end of every benchmark's main: writes `records` to `file_name` in the output directory and returns main's exit
// code (1, with a message on stderr, when the file cannot be written).
inline int finish(const JsonRecords& records, const Options& options, const std::string& file_name) {
  const std::string path = options.out_dir + "/" + file_name;
  if (!records.write(path)) {
    std::fprintf(stderr, "cannot write %s\n", path.c_str());
    return 1;
  }
  std::printf("wrote %s\n", path.c_str());
  return 0;
}

}  // namespace bench
