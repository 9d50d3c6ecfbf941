// Loaders for STL, PLY, legacy VTK and VTK XML PolyData (.vtp) through VTK's readers, Wavefront OBJ through a small
// reader of its own, and two writers through VTK's (the polyline writer's fixed-decimal ASCII form excepted: VTK
// writes ASCII doubles with 11 significant digits).
//
// VTK's readers report a problem as a message, not an exception, and VTK 9.1's (Debian 12) go on after some of them:
// a legacy file with a coordinate missing loads with a wrong point, and a legacy cell list that ends early or a PLY
// file without vertex coordinates crashes the reader a step later. So every message a reader gives fails the load at once (VtkMessages below),
// and the output is checked again (finite points, point ids in range, polygon sizes), because some readers accept
// what they should not: a binary STL shorter than its header says, a NaN coordinate, a point id out of range.
//
// OBJ is not read with vtkOBJReader: VTK 9.1's copies a vertex for every face corner that names a texture coordinate
// or normal (the surface is no longer welded), drops faces whose v/vt/vn form differs from the first face's, does
// not resolve negative (relative) indices and reads '1.0x' as 1.0.
#include "muscle_deformation/core/io/mesh_io.hpp"

#include "poly_data_conversion.hpp"

#include <vtkCallbackCommand.h>
#include <vtkCellArray.h>
#include <vtkCommand.h>
#include <vtkDataArraySelection.h>
#include <vtkDataWriter.h>
#include <vtkExecutive.h>
#include <vtkLogger.h>
#include <vtkNew.h>
#include <vtkObjectFactory.h>
#include <vtkOutputWindow.h>
#include <vtkPLYReader.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataReader.h>
#include <vtkPolyDataWriter.h>
#include <vtkSTLReader.h>
#include <vtkSTLWriter.h>
#include <vtkSmartPointer.h>
#include <vtkWriter.h>
#include <vtkXMLDataElement.h>
#include <vtkXMLDataParser.h>
#include <vtkXMLPolyDataReader.h>

#include <array>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string_view>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

namespace muscle_deformation {

namespace {

// ---------------------------------------------------------------------------------------------------------------
// Errors, names and numbers

[[noreturn]] void fail(const std::string& path, const std::string& msg) { throw LoadError(path + ": " + msg); }

[[noreturn]] void failAtLine(const std::string& path, long line, const std::string& msg) {
  throw LoadError(path + " line " + std::to_string(line) + ": " + msg);
}

// A token as it appears in messages: quoted, shortened so binary garbage cannot flood the terminal.
std::string quoted(std::string_view token) {
  std::string out = "'";
  for (char ch : token.substr(0, 40)) out += std::isprint(static_cast<unsigned char>(ch)) ? ch : '?';
  if (token.size() > 40) out += "...";
  return out + "'";
}

std::string lowerExtension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& ch : ext) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  return ext;
}

// Locale-independent and exact; accepts a leading '+' which from_chars alone rejects.
bool parseDouble(std::string_view s, double& out) {
  if (!s.empty() && s[0] == '+') s.remove_prefix(1);
  if (s.empty()) return false;
  const auto result = std::from_chars(s.data(), s.data() + s.size(), out);
  return result.ec == std::errc() && result.ptr == s.data() + s.size();
}

bool parseInt(std::string_view s, long long& out) {
  if (!s.empty() && s[0] == '+') s.remove_prefix(1);
  if (s.empty()) return false;
  const auto result = std::from_chars(s.data(), s.data() + s.size(), out);
  return result.ec == std::errc() && result.ptr == s.data() + s.size();
}

void checkScale(const std::string& path, double scale) {
  if (!std::isfinite(scale) || scale <= 0.0) {
    fail(path, "scale_to_metres must be a positive finite number, got " + std::to_string(scale));
  }
}

// The checks every reader needs before it opens the file, with one wording for all formats.
void checkReadableFile(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) fail(path, "file not found");
  if (std::filesystem::is_directory(path, ec)) fail(path, "is a directory, not a mesh file");
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, std::string("cannot open file: ") + std::strerror(errno));
  if (in.peek() == std::ifstream::traits_type::eof()) fail(path, "file is empty");
}

std::string readWholeFile(const std::string& path) {
  checkReadableFile(path);
  std::ifstream in(path, std::ios::binary);
  std::ostringstream content;
  content << in.rdbuf();
  if (in.bad()) fail(path, "read error");
  return content.str();
}

// ---------------------------------------------------------------------------------------------------------------
// VTK's messages

const char* const kReaderFailed = "the reader failed";

// VTK formats a message as "ERROR: In <VTK source file>, line <n>\n<class> (<address>): <text>\n\n"; only <text>
// says something about the file, and it goes on one line.
std::string messageText(const char* raw) {
  std::string text = raw != nullptr ? raw : "";
  for (const char* head : {"ERROR: In ", "Warning: In ", "Generic Warning: In ", "Debug: In "}) {
    if (text.rfind(head, 0) == 0) {
      const std::size_t newline = text.find('\n');
      text = newline == std::string::npos ? std::string() : text.substr(newline + 1);
      break;
    }
  }
  const std::size_t address = text.find(" (0x");
  const std::size_t colon = text.find("): ");
  if (address != std::string::npos && colon != std::string::npos && address < colon &&
      text.find_first_of(" \n") == address) {
    text = text.substr(colon + 3);
  }
  // The pipeline's own report that a reader failed carries a dump of pipeline requests, nothing about the file.
  if (text.find("returned failure for request") != std::string::npos) return kReaderFailed;
  std::string line;
  for (char ch : text) {
    const bool space = std::isspace(static_cast<unsigned char>(ch)) != 0;
    if (space && (line.empty() || line.back() == ' ')) continue;
    line += space ? ' ' : ch;
  }
  while (!line.empty() && line.back() == ' ') line.pop_back();
  return line;
}

class VtkMessages;

// Takes what VTK would print (messages of objects nobody observes, generic warnings) on the reading thread; other
// threads' messages go on to the window that was there before.
class MessageWindow : public vtkOutputWindow {
 public:
  static MessageWindow* New();
  vtkTypeMacro(MessageWindow, vtkOutputWindow);

  void DisplayText(const char* text) override { route(text, &vtkOutputWindow::DisplayText); }
  void DisplayErrorText(const char* text) override { route(text, &vtkOutputWindow::DisplayErrorText); }
  void DisplayWarningText(const char* text) override { route(text, &vtkOutputWindow::DisplayWarningText); }
  void DisplayGenericWarningText(const char* text) override {
    route(text, &vtkOutputWindow::DisplayGenericWarningText);
  }
  void DisplayDebugText(const char* text) override { route(text, &vtkOutputWindow::DisplayDebugText); }

  VtkMessages* sink = nullptr;
  std::thread::id thread;
  vtkSmartPointer<vtkOutputWindow> previous;

 private:
  void route(const char* text, void (vtkOutputWindow::*display)(const char*));
};
vtkStandardNewMacro(MessageWindow);

// Everything VTK says while one reader or writer runs on this thread: an observer on the algorithm and its executive
// (and on the XML parser, through SetParserErrorObserver) takes their messages, a MessageWindow the rest, and
// vtkLogger, which would print them to stderr, is silenced meanwhile. One at a time in the process.
//
// at_once: the first message throws LoadError("<path>: cannot be read as <format>: <message>") from inside the
// reader, the only way to stop VTK 9.1's legacy and PLY readers before they crash on the input. VTK's reader
// algorithms may catch it and return an empty output, so callers still call throwIfAny() after Update. Not for the
// XML reader, whose messages can come from inside expat (C code, which an exception must not cross): it collects
// them, and the caller calls throwIfAny() after each step.
class VtkMessages {
 public:
  enum class Mode { at_once, collect };

  VtkMessages(std::string path, std::string format, Mode mode)
      : lock_(mutex()), path_(std::move(path)), format_(std::move(format)), mode_(mode) {
    window_ = vtkSmartPointer<MessageWindow>::New();
    window_->previous = vtkOutputWindow::GetInstance();
    window_->thread = std::this_thread::get_id();
    window_->sink = this;
    vtkOutputWindow::SetInstance(window_);
    // vtkLogger has no getter for the stderr level; the cutoff is that level unless someone added a more verbose
    // log callback or file.
    logger_level_ = vtkLogger::GetCurrentVerbosityCutoff();
    vtkLogger::SetStderrVerbosity(vtkLogger::VERBOSITY_OFF);
    command_ = vtkSmartPointer<vtkCallbackCommand>::New();
    command_->SetClientData(this);
    command_->SetCallback([](vtkObject*, unsigned long, void* self, void* text) {
      static_cast<VtkMessages*>(self)->add(static_cast<const char*>(text));
    });
  }

  ~VtkMessages() {
    vtkLogger::SetStderrVerbosity(logger_level_);
    window_->sink = nullptr;
    vtkOutputWindow::SetInstance(window_->previous);
  }

  VtkMessages(const VtkMessages&) = delete;
  VtkMessages& operator=(const VtkMessages&) = delete;

  void watch(vtkObject* object) {
    object->AddObserver(vtkCommand::ErrorEvent, command_);
    object->AddObserver(vtkCommand::WarningEvent, command_);
  }
  vtkCommand* command() const { return command_; }

  void add(const char* raw) {
    std::string text = messageText(raw);
    // The pipeline's "the reader failed" adds nothing to the reader's own account.
    if (text.empty() || (text == kReaderFailed && !texts_.empty())) return;
    texts_.push_back(std::move(text));
    if (mode_ == Mode::at_once) throwIfAny();
  }

  bool empty() const { return texts_.empty(); }
  std::string text() const {
    std::string joined;
    for (const std::string& t : texts_) joined += (joined.empty() ? "" : "; ") + t;
    return joined;
  }
  void throwIfAny() const {
    if (!texts_.empty()) fail(path_, "cannot be read as " + format_ + ": " + text());
  }

 private:
  static std::mutex& mutex() {
    static std::mutex m;
    return m;
  }

  std::lock_guard<std::mutex> lock_;
  std::string path_;
  std::string format_;
  Mode mode_;
  vtkSmartPointer<MessageWindow> window_;
  vtkSmartPointer<vtkCallbackCommand> command_;
  vtkLogger::Verbosity logger_level_ = vtkLogger::VERBOSITY_OFF;
  std::vector<std::string> texts_;
};

void MessageWindow::route(const char* text, void (vtkOutputWindow::*display)(const char*)) {
  if (sink != nullptr && std::this_thread::get_id() == thread) {
    if (display != &vtkOutputWindow::DisplayDebugText) sink->add(text);
  } else if (previous != nullptr) {
    (previous.Get()->*display)(text);
  }
}

// ---------------------------------------------------------------------------------------------------------------
// Checks of what a reader produced

void checkPoints(const std::string& path, vtkPolyData* data) {
  if (data == nullptr || data->GetNumberOfPoints() == 0) fail(path, "contains no points");
  for (vtkIdType i = 0; i < data->GetNumberOfPoints(); ++i) {
    double p[3];
    data->GetPoint(i, p);
    if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) {
      fail(path, "point " + std::to_string(i) + " has a NaN or infinite coordinate");
    }
  }
}

void checkPointIds(const std::string& path, vtkCellArray* cells, const char* kind, vtkIdType points) {
  vtkIdType count = 0;
  const vtkIdType* ids = nullptr;
  vtkIdType cell = 0;
  for (cells->InitTraversal(); cells->GetNextCell(count, ids); ++cell) {
    for (vtkIdType k = 0; k < count; ++k) {
      if (ids[k] < 0 || ids[k] >= points) {
        fail(path, std::string(kind) + " " + std::to_string(cell) + " refers to point " + std::to_string(ids[k]) +
                       " but there are only " + std::to_string(points) + " points (valid: 0 to " +
                       std::to_string(points - 1) + ")");
      }
    }
  }
}

// Finite points, and every cell's point ids in range.
void checkPolyData(const std::string& path, vtkPolyData* data) {
  checkPoints(path, data);
  const vtkIdType points = data->GetNumberOfPoints();
  checkPointIds(path, data->GetVerts(), "vertex cell", points);
  checkPointIds(path, data->GetLines(), "line", points);
  checkPointIds(path, data->GetPolys(), "polygon", points);
  checkPointIds(path, data->GetStrips(), "triangle strip", points);
}

void checkAtLeastThree(const std::string& path, vtkCellArray* cells, const char* kind) {
  vtkIdType count = 0;
  const vtkIdType* ids = nullptr;
  vtkIdType cell = 0;
  for (cells->InitTraversal(); cells->GetNextCell(count, ids); ++cell) {
    if (count < 3) {
      fail(path, std::string(kind) + " " + std::to_string(cell) + " has " + std::to_string(count) +
                     " vertices; at least 3 are needed");
    }
  }
}

// `data` passed checkPolyData.
TriangleMesh trianglesOf(const std::string& path, vtkPolyData* data, double scale) {
  checkAtLeastThree(path, data->GetPolys(), "polygon");
  checkAtLeastThree(path, data->GetStrips(), "triangle strip");
  if (data->GetNumberOfPolys() == 0 && data->GetNumberOfStrips() == 0) {
    if (data->GetNumberOfLines() > 0) {
      fail(path, "contains no triangles, only " + std::to_string(data->GetNumberOfLines()) +
                     " lines (is this a fibre file? read it with loadPolylines)");
    }
    fail(path, "contains no triangles");
  }
  return toTriangleMesh(data, scale);
}

// `data` passed checkPolyData.
std::vector<Polyline> polylinesOf(const std::string& path, vtkPolyData* data, double scale) {
  if (data->GetNumberOfLines() == 0) {
    if (data->GetNumberOfPolys() > 0 || data->GetNumberOfStrips() > 0) {
      fail(path, "contains no lines, only surface polygons (is this a surface file? read it with loadTriangleMesh)");
    }
    fail(path, "contains no lines");
  }
  std::vector<Polyline> lines;
  lines.reserve(static_cast<std::size_t>(data->GetNumberOfLines()));
  vtkIdType count = 0;
  const vtkIdType* ids = nullptr;
  vtkCellArray* cells = data->GetLines();
  for (cells->InitTraversal(); cells->GetNextCell(count, ids);) {
    // A line of fewer than 2 points is kept: the model skips it with a warning, as it skips a zero-length or
    // non-finite one (one rule for every degenerate fibre, applied where fibres are used).
    Polyline line(3, count);
    for (vtkIdType k = 0; k < count; ++k) {
      double p[3];
      data->GetPoint(ids[k], p);
      for (int d = 0; d < 3; ++d) line(d, k) = p[d] * scale;
    }
    lines.push_back(std::move(line));
  }
  return lines;
}

// ---------------------------------------------------------------------------------------------------------------
// STL

// Merges exactly equal coordinates into one vertex, keeping first-appearance order (VTK's own merging also drops
// the triangles it makes degenerate, which would hide them from the topology checks).
class VertexWelder {
 public:
  int add(const double (&p)[3]) {
    // +0 and -0 compare equal, so they must hash equally; the vertex keeps +0.
    const Key key{{p[0] == 0.0 ? 0.0 : p[0], p[1] == 0.0 ? 0.0 : p[1], p[2] == 0.0 ? 0.0 : p[2]}};
    const auto inserted = index_.emplace(key, static_cast<int>(xyz_.size()));
    if (inserted.second) xyz_.push_back(key.c);
    return inserted.first->second;
  }
  Vertices vertices(double scale) const {
    Vertices v(3, static_cast<Eigen::Index>(xyz_.size()));
    for (std::size_t i = 0; i < xyz_.size(); ++i) {
      for (int k = 0; k < 3; ++k) v(k, static_cast<Eigen::Index>(i)) = xyz_[i][static_cast<std::size_t>(k)] * scale;
    }
    return v;
  }

 private:
  struct Key {
    std::array<double, 3> c;
    bool operator==(const Key& o) const { return c == o.c; }
  };
  struct KeyHash {
    std::size_t operator()(const Key& k) const {
      std::uint64_t h = 1469598103934665603ull;
      for (double d : k.c) {
        std::uint64_t bits;
        std::memcpy(&bits, &d, sizeof bits);
        h = (h ^ bits) * 1099511628211ull;
        h ^= h >> 29;
      }
      return static_cast<std::size_t>(h);
    }
  };
  std::unordered_map<Key, int, KeyHash> index_;
  std::vector<std::array<double, 3>> xyz_;
};

std::uint32_t littleEndian32(const char* p) {
  std::uint32_t value = 0;
  for (int i = 3; i >= 0; --i) value = (value << 8) | static_cast<unsigned char>(p[i]);
  return value;
}

// Which kind of STL the file is, by the rule VTK does not check: a binary STL is exactly 84 + 50 n bytes for the n
// triangles its header declares (decisive, since some binary writers start the header with "solid" too). Returns
// the declared count for a binary file, -1 for ASCII; refuses a file that is neither (e.g. a truncated binary one,
// which vtkSTLReader would read as far as it goes).
long long stlTriangleCount(const std::string& path) {
  checkReadableFile(path);
  std::error_code ec;
  const std::uintmax_t size = std::filesystem::file_size(path, ec);
  char header[84] = {};
  std::ifstream(path, std::ios::binary).read(header, sizeof header);
  if (!ec && size >= 84) {
    const std::uint32_t n = littleEndian32(header + 80);
    if (84 + 50 * static_cast<std::uint64_t>(n) == size) {
      if (n == 0) fail(path, "binary STL contains no triangles");
      return n;
    }
  }
  const std::string data = readWholeFile(path);
  std::size_t first = 0;
  while (first < data.size() && std::isspace(static_cast<unsigned char>(data[first]))) ++first;
  std::string start = data.substr(first, 5);
  for (char& ch : start) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  if (start == "solid" && std::memchr(data.data(), '\0', data.size()) == nullptr) return -1;
  if (data.size() < 84) {
    fail(path, "too short for a binary STL (" + std::to_string(data.size()) +
                   " bytes, the header alone is 84) and not an ASCII STL (does not start with 'solid')");
  }
  const std::uint32_t n = littleEndian32(data.data() + 80);
  fail(path, "truncated or corrupt binary STL: header declares " + std::to_string(n) + " triangles, which needs " +
                 std::to_string(84 + 50 * static_cast<std::uint64_t>(n)) + " bytes, but the file has " +
                 std::to_string(data.size()) + " bytes");
}

TriangleMesh readStl(const std::string& path, double scale) {
  const long long declared = stlTriangleCount(path);
  vtkNew<vtkSTLReader> reader;
  reader->SetFileName(path.c_str());
  reader->MergingOff();
  reader->ScalarTagsOff();
  VtkMessages messages(path, "STL", VtkMessages::Mode::at_once);
  messages.watch(reader);
  messages.watch(reader->GetExecutive());
  reader->Update();
  messages.throwIfAny();
  vtkPolyData* data = reader->GetOutput();
  const vtkIdType triangles = data->GetNumberOfPolys();
  if (triangles == 0) fail(path, "contains no triangles (no 'facet' records)");
  // vtkSTLReader tells binary from ASCII by the bytes it finds, not by the size rule above.
  if (declared >= 0 && triangles != declared) {
    fail(path, "binary STL declares " + std::to_string(declared) + " triangles but " + std::to_string(triangles) +
                   " were read");
  }
  // Not merged: triangle t's corners are points of its own, in the file's order.
  VertexWelder welder;
  std::vector<int> corners;
  corners.reserve(3 * static_cast<std::size_t>(triangles));
  vtkIdType count = 0;
  const vtkIdType* ids = nullptr;
  vtkIdType t = 0;
  vtkCellArray* polys = data->GetPolys();
  for (polys->InitTraversal(); polys->GetNextCell(count, ids); ++t) {
    if (count != 3) {
      fail(path, "facet " + std::to_string(t) + " has " + std::to_string(count) + " vertices; STL facets must have 3");
    }
    for (vtkIdType k = 0; k < 3; ++k) {
      double p[3];
      data->GetPoint(ids[k], p);
      if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) {
        fail(path, "triangle " + std::to_string(t) + " has a NaN or infinite vertex coordinate");
      }
      corners.push_back(welder.add(p));
    }
  }
  TriangleMesh mesh;
  mesh.vertices = welder.vertices(scale);
  mesh.triangles = Eigen::Map<const Triangles>(corners.data(), 3, static_cast<Eigen::Index>(corners.size() / 3));
  return mesh;
}

// ---------------------------------------------------------------------------------------------------------------
// Legacy VTK, VTK XML PolyData and PLY

// Whether `token` is a number that becomes NaN or infinite as a T: 'nan', 'inf', '-inf', 'infinity' (any case) or a
// number beyond T's range. Not a number at all: false, for the reader to report as it does.
template <typename T>
bool notFiniteAs(std::string_view token) {
  if (!token.empty() && token[0] == '+') token.remove_prefix(1);
  T value;
  const auto result = std::from_chars(token.data(), token.data() + token.size(), value);
  if (result.ptr != token.data() + token.size()) return false;
  if (result.ec == std::errc()) return !std::isfinite(value);
  if (result.ec != std::errc::result_out_of_range) return false;
  // Out of range is either side: beyond T's largest value (infinite for a reader) or below its smallest (zero).
  long double wide;
  const auto again = std::from_chars(token.data(), token.data() + token.size(), wide);
  return again.ec == std::errc() && std::fabs(wide) > std::numeric_limits<T>::max();
}

// VTK's legacy reader reads ASCII numbers with C++ streams, which take neither 'nan' nor 'inf' (nor a number beyond
// the range of the POINTS' declared type): it stops at such a coordinate with "Error reading ascii data. Possible
// mismatch of datasize with declaration", which names neither the point nor the line. So the POINTS of an ASCII file
// are looked through before VTK reads it, and the first coordinate that is not a finite number of the declared type
// is refused here, naming its point and line. What this scan does not follow (not an ASCII legacy file, no POINTS,
// an integer type, a token that is no number) it leaves to VTK's reader, which reports it as before.
void checkAsciiLegacyPoints(const std::string& path) {
  const auto upper = [](std::string_view token) {
    std::string out(token);
    for (char& ch : out) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
    return out;
  };
  {
    // The third line says ASCII or BINARY; a BINARY file is not read twice (its NaN is read as one, and checkPoints
    // names the point).
    std::ifstream in(path, std::ios::binary);
    std::string first, title, format;
    if (!std::getline(in, first) || !std::getline(in, title) || !std::getline(in, format)) return;
    while (!format.empty() && std::isspace(static_cast<unsigned char>(format.back()))) format.pop_back();
    if (upper(format) != "ASCII") return;
  }
  const std::string text = readWholeFile(path);
  long line = 1;
  std::size_t at = 0;
  // The header's three lines (the second, the title, is free text).
  for (int k = 0; k < 3 && at < text.size(); ++k) {
    at = text.find('\n', at);
    at = at == std::string::npos ? text.size() : at + 1;
    ++line;
  }
  long token_line = line;
  const auto next = [&](std::string_view& token) {
    while (at < text.size() && std::isspace(static_cast<unsigned char>(text[at]))) {
      if (text[at] == '\n') ++line;
      ++at;
    }
    const std::size_t start = at;
    while (at < text.size() && !std::isspace(static_cast<unsigned char>(text[at]))) ++at;
    token = std::string_view(text.data() + start, at - start);
    token_line = line;
    return !token.empty();
  };
  std::string_view token;
  bool found = false;
  while (!found && next(token)) found = upper(token) == "POINTS";
  long long count = 0;
  if (!found || !next(token) || !parseInt(token, count) || count < 0 || !next(token)) return;
  const std::string type = upper(token);
  if (type != "FLOAT" && type != "DOUBLE") return;
  for (long long i = 0; i < 3 * count; ++i) {
    if (!next(token)) return;
    const std::string point = "point " + std::to_string(i / 3);
    if (notFiniteAs<double>(token))
      failAtLine(path, token_line, point + " has a NaN or infinite coordinate: " + quoted(token));
    if (type == "FLOAT" && notFiniteAs<float>(token))
      failAtLine(path, token_line, point + " has a coordinate beyond the range of float, the type its POINTS declare: " +
                                       quoted(token));
  }
}

vtkSmartPointer<vtkPolyData> readLegacyVtk(const std::string& path) {
  checkAsciiLegacyPoints(path);
  vtkNew<vtkPolyDataReader> reader;
  reader->SetFileName(path.c_str());
  VtkMessages messages(path, "legacy VTK polydata", VtkMessages::Mode::at_once);
  messages.watch(reader);
  messages.watch(reader->GetExecutive());
  reader->Update();
  messages.throwIfAny();  // VTK's reader algorithms catch the exception and return an empty output
  return reader->GetOutput();
}

// vtkXMLPolyDataReader keeps a Float32 DataArray as float also when the file writes it as decimal text (OpenSim's
// bone meshes do); the loaders have always returned the text's own value, as a double, so the points of such arrays
// are read again as doubles with VTK's XML parser. Point p of piece k is point (points of pieces before k) + p of
// the reader's output.
void readTextPointsAsDouble(const std::string& path, vtkPolyData* data, VtkMessages& messages) {
  std::ifstream stream(path, std::ios::binary);
  vtkNew<vtkXMLDataParser> parser;
  parser->AddObserver(vtkCommand::ErrorEvent, messages.command());
  parser->AddObserver(vtkCommand::WarningEvent, messages.command());
  parser->SetStream(&stream);
  const int parsed = parser->Parse();
  messages.throwIfAny();
  vtkXMLDataElement* root = parsed ? parser->GetRootElement() : nullptr;
  vtkXMLDataElement* polydata = root != nullptr ? root->FindNestedElementWithName("PolyData") : nullptr;
  if (polydata == nullptr) return;
  vtkSmartPointer<vtkPoints> points;
  vtkIdType first = 0;
  for (int i = 0; i < polydata->GetNumberOfNestedElements(); ++i) {
    vtkXMLDataElement* piece = polydata->GetNestedElement(i);
    if (std::strcmp(piece->GetName(), "Piece") != 0) continue;
    long count = 0;
    piece->GetScalarAttribute("NumberOfPoints", count);
    vtkXMLDataElement* point_node = piece->FindNestedElementWithName("Points");
    vtkXMLDataElement* array = point_node != nullptr ? point_node->FindNestedElementWithName("DataArray") : nullptr;
    const char* format = array != nullptr ? array->GetAttribute("format") : nullptr;
    const char* type = array != nullptr ? array->GetAttribute("type") : nullptr;
    if (count > 0 && format != nullptr && type != nullptr && std::strcmp(format, "ascii") == 0 &&
        std::strcmp(type, "Float32") == 0) {
      if (first + count > data->GetNumberOfPoints()) return;  // not the layout the reader produced: keep its points
      std::vector<double> xyz(3 * static_cast<std::size_t>(count));
      if (parser->ReadInlineData(array, 1, xyz.data(), 0, xyz.size(), VTK_DOUBLE) != xyz.size()) {
        messages.throwIfAny();
        fail(path, "cannot be read as VTK XML PolyData: the Points of piece " + std::to_string(i) +
                       " hold fewer numbers than 3 per point");
      }
      if (points == nullptr) {
        points = vtkSmartPointer<vtkPoints>::New();
        points->SetDataTypeToDouble();
        points->SetNumberOfPoints(data->GetNumberOfPoints());
        for (vtkIdType p = 0; p < data->GetNumberOfPoints(); ++p) points->SetPoint(p, data->GetPoint(p));
      }
      for (vtkIdType p = 0; p < count; ++p) points->SetPoint(first + p, &xyz[3 * static_cast<std::size_t>(p)]);
    }
    first += count;
  }
  if (points != nullptr) data->SetPoints(points);
}

vtkSmartPointer<vtkPolyData> readVtp(const std::string& path) {
  vtkNew<vtkXMLPolyDataReader> reader;
  reader->SetFileName(path.c_str());
  VtkMessages messages(path, "VTK XML PolyData", VtkMessages::Mode::collect);
  messages.watch(reader);
  messages.watch(reader->GetExecutive());
  reader->SetParserErrorObserver(messages.command());
  reader->UpdateInformation();
  messages.throwIfAny();
  // Point and cell data carry nothing a mesh or a fibre needs.
  reader->GetPointDataArraySelection()->DisableAllArrays();
  reader->GetCellDataArraySelection()->DisableAllArrays();
  reader->Update();
  messages.throwIfAny();
  vtkSmartPointer<vtkPolyData> data = reader->GetOutput();
  readTextPointsAsDouble(path, data, messages);
  return data;
}

vtkSmartPointer<vtkPolyData> readPly(const std::string& path) {
  vtkNew<vtkPLYReader> reader;
  reader->SetFileName(path.c_str());
  reader->SetDuplicatePointsForFaceTexture(false);  // point i stays vertex i of the file
  VtkMessages messages(path, "PLY", VtkMessages::Mode::at_once);
  messages.watch(reader);
  messages.watch(reader->GetExecutive());
  reader->Update();
  messages.throwIfAny();  // VTK's reader algorithms catch the exception and return an empty output
  return reader->GetOutput();
}

// ---------------------------------------------------------------------------------------------------------------
// Wavefront OBJ: v, f and l records (f and l may use v/vt/vn and negative indices); everything else is skipped.

vtkSmartPointer<vtkPolyData> readObj(const std::string& path) {
  const std::string text = readWholeFile(path);
  std::vector<double> xyz;
  std::vector<std::vector<vtkIdType>> faces, lines;
  // Positive indices may in principle refer to vertices defined later, so they are checked at the end.
  std::vector<std::pair<long, long long>> deferred;  // (line, 1-based index)
  long line_number = 0;
  std::size_t pos = 0;
  std::string logical;

  auto resolve = [&](std::string_view ref, long line, const char* record) -> vtkIdType {
    const std::string_view index_text = ref.substr(0, ref.find('/'));
    long long index;
    if (!parseInt(index_text, index)) {
      failAtLine(path, line, std::string("expected a vertex index in '") + record + "' record, found " + quoted(ref));
    }
    if (index == 0) failAtLine(path, line, std::string("vertex index 0 in '") + record + "' record; OBJ indices start at 1");
    const auto defined = static_cast<long long>(xyz.size() / 3);
    if (index < 0) {
      if (-index > defined) {
        failAtLine(path, line, "relative vertex index " + std::to_string(index) + " reaches before the first vertex (only " +
                                   std::to_string(defined) + " vertices defined so far)");
      }
      return defined + index;
    }
    deferred.emplace_back(line, index);
    return index - 1;
  };

  while (pos < text.size()) {
    // Join continuation lines (a trailing backslash) into one logical record.
    logical.clear();
    const long first_line = line_number + 1;
    while (pos < text.size()) {
      std::size_t end = text.find('\n', pos);
      if (end == std::string::npos) end = text.size();
      std::string_view physical(text.data() + pos, end - pos);
      pos = end + 1;
      ++line_number;
      if (!physical.empty() && physical.back() == '\r') physical.remove_suffix(1);
      if (!physical.empty() && physical.back() == '\\') {
        physical.remove_suffix(1);
        logical.append(physical).push_back(' ');
        continue;
      }
      logical.append(physical);
      break;
    }
    const std::size_t hash = logical.find('#');
    if (hash != std::string::npos) logical.resize(hash);

    std::vector<std::string_view> tokens;
    for (std::size_t at = 0; at < logical.size();) {
      while (at < logical.size() && std::isspace(static_cast<unsigned char>(logical[at]))) ++at;
      const std::size_t start = at;
      while (at < logical.size() && !std::isspace(static_cast<unsigned char>(logical[at]))) ++at;
      if (at > start) tokens.emplace_back(logical.data() + start, at - start);
    }
    if (tokens.empty()) continue;
    const std::string_view keyword = tokens[0];
    if (keyword == "v") {
      double c[3];
      for (std::size_t k = 0; k < 3; ++k) {
        if (k + 1 >= tokens.size()) {
          failAtLine(path, first_line, "expected 3 coordinates per vertex ('v x y z'), found " + std::to_string(k));
        }
        const std::string_view tok = tokens[k + 1];
        if (!parseDouble(tok, c[k])) failAtLine(path, first_line, "vertex coordinate " + quoted(tok) + " is not a number");
        if (!std::isfinite(c[k])) failAtLine(path, first_line, "vertex coordinate " + quoted(tok) + " is not finite");
      }
      // Optional w or colour values may follow; they must still be numbers.
      for (std::size_t k = 4; k < tokens.size(); ++k) {
        double ignored;
        if (!parseDouble(tokens[k], ignored)) {
          failAtLine(path, first_line, "unexpected " + quoted(tokens[k]) + " after the vertex coordinates");
        }
      }
      xyz.insert(xyz.end(), c, c + 3);
    } else if (keyword == "f" || keyword == "l") {
      const bool face = keyword == "f";
      std::vector<vtkIdType> cell;
      for (std::size_t k = 1; k < tokens.size(); ++k) cell.push_back(resolve(tokens[k], first_line, face ? "f" : "l"));
      if (face && cell.size() < 3) {
        failAtLine(path, first_line, "face has " + std::to_string(cell.size()) + " vertices; at least 3 are needed");
      }
      if (!face && cell.size() < 2) {
        failAtLine(path, first_line, "line has " + std::to_string(cell.size()) + " vertices; at least 2 are needed");
      }
      (face ? faces : lines).push_back(std::move(cell));
    }
    // Everything else (vt, vn, g, o, s, usemtl, mtllib, ...) carries nothing we need.
  }
  const auto defined = static_cast<long long>(xyz.size() / 3);
  for (const auto& entry : deferred) {
    if (entry.second > defined) {
      failAtLine(path, entry.first, "vertex index " + std::to_string(entry.second) + " is out of range: the file defines only " +
                                        std::to_string(defined) + " vertices");
    }
  }

  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(defined);
  for (vtkIdType i = 0; i < defined; ++i) points->SetPoint(i, &xyz[3 * static_cast<std::size_t>(i)]);
  vtkNew<vtkCellArray> polys;
  for (const auto& cell : faces) polys->InsertNextCell(static_cast<vtkIdType>(cell.size()), cell.data());
  vtkNew<vtkCellArray> polylines;
  for (const auto& cell : lines) polylines->InsertNextCell(static_cast<vtkIdType>(cell.size()), cell.data());
  auto data = vtkSmartPointer<vtkPolyData>::New();
  data->SetPoints(points);
  data->SetPolys(polys);
  data->SetLines(polylines);
  return data;
}

// ---------------------------------------------------------------------------------------------------------------

// A checked polydata from a .vtk, .vtp, .ply or .obj file.
vtkSmartPointer<vtkPolyData> readPolyData(const std::string& path, const std::string& ext) {
  vtkSmartPointer<vtkPolyData> data;
  if (ext == ".obj") {
    data = readObj(path);
  } else {
    checkReadableFile(path);
    data = ext == ".vtk" ? readLegacyVtk(path) : ext == ".vtp" ? readVtp(path) : readPly(path);
  }
  checkPolyData(path, data);
  return data;
}

[[noreturn]] void unknownExtension(const std::string& path, const std::string& ext, const char* supported) {
  fail(path, (ext.empty() ? std::string("has no file extension") : "unknown file extension '" + ext + "'") +
                 "; supported: " + supported);
}

// Runs a writer; throws std::runtime_error naming the file and what VTK said if it fails.
void write(const std::string& path, vtkWriter* writer) {
  VtkMessages messages(path, "", VtkMessages::Mode::collect);
  messages.watch(writer);
  messages.watch(writer->GetExecutive());
  const int ok = writer->Write();
  if (ok != 1 || !messages.empty()) {
    throw std::runtime_error(path + ": cannot write the file: " +
                             (messages.empty() ? std::string("write failed") : messages.text()));
  }
}

// savePolylinesVtk's ASCII form (lines already checked).
void writePolylinesAscii(const std::string& path, const std::vector<Polyline>& lines, const std::string& title,
                         int decimals) {
  std::size_t points = 0;
  for (const Polyline& line : lines) points += static_cast<std::size_t>(line.cols());
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot open for writing: " + std::strerror(errno));
  out << "# vtk DataFile Version 3.0\n" << title << "\nASCII\nDATASET POLYDATA\n";
  out << "POINTS " << points << " double\n";
  // Fixed decimals with trailing zeros dropped: short, exact to the chosen precision, readable by any VTK reader.
  auto number = [decimals](double value) {
    char buffer[64];
    std::snprintf(buffer, sizeof buffer, "%.*f", decimals, value);
    std::string text = buffer;
    text.erase(text.find_last_not_of('0') + 1);
    if (text.back() == '.') text.pop_back();
    if (text == "-0") text = "0";
    return text;
  };
  for (const Polyline& line : lines) {
    for (Eigen::Index i = 0; i < line.cols(); ++i) {
      out << number(line(0, i)) << ' ' << number(line(1, i)) << ' ' << number(line(2, i)) << '\n';
    }
  }
  out << "LINES " << lines.size() << ' ' << (points + lines.size()) << '\n';
  std::size_t next = 0;
  for (const Polyline& line : lines) {
    out << line.cols();
    for (Eigen::Index i = 0; i < line.cols(); ++i) out << ' ' << next++;
    out << '\n';
  }
  out.close();
  if (!out) throw std::runtime_error(path + ": write failed");
}

}  // namespace

TriangleMesh loadTriangleMesh(const std::string& path, double scale_to_metres) {
  checkScale(path, scale_to_metres);
  const std::string ext = lowerExtension(path);
  if (ext == ".stl") return readStl(path, scale_to_metres);
  if (ext == ".vtk" || ext == ".vtp" || ext == ".ply" || ext == ".obj") {
    return trianglesOf(path, readPolyData(path, ext), scale_to_metres);
  }
  unknownExtension(path, ext, ".stl, .vtk, .vtp, .obj, .ply");
}

TriangleMesh loadClosedSurface(const std::string& path, double scale_to_metres) {
  TriangleMesh mesh = loadTriangleMesh(path, scale_to_metres);
  const SurfaceTopologyReport report = checkSurfaceTopology(mesh);
  if (!report.closedManifold()) {
    fail(path, "is not a closed, consistently oriented 2-manifold surface: " + report.describe() +
                   " (small defects can be repaired: the scene's repair_surfaces: true, or generate_fibres without "
                   "--no-repair)");
  }
  return mesh;
}

std::vector<Polyline> loadPolylines(const std::string& path, double scale_to_metres) {
  checkScale(path, scale_to_metres);
  const std::string ext = lowerExtension(path);
  if (ext == ".vtk" || ext == ".vtp" || ext == ".obj") {
    return polylinesOf(path, readPolyData(path, ext), scale_to_metres);
  }
  if (ext == ".stl" || ext == ".ply") {
    fail(path, std::string(ext == ".stl" ? "STL" : "PLY") +
                   " files hold triangles, not polylines; fibres must be .vtk, .vtp or .obj");
  }
  unknownExtension(path, ext, ".vtk, .vtp, .obj");
}

// Writers throw std::runtime_error naming the file: they are not loaders.
void savePolylinesVtk(const std::string& path, const std::vector<Polyline>& lines, const std::string& title,
                      int decimals) {
  if (decimals < 0 || decimals > 17) throw std::invalid_argument("savePolylinesVtk: decimals must be in 0..17");
  if (title.size() > kLegacyVtkTitleLimit || title.find('\n') != std::string::npos) {
    throw std::invalid_argument("savePolylinesVtk: the title must be one line of at most " +
                                std::to_string(kLegacyVtkTitleLimit) + " characters");
  }
  vtkIdType point_count = 0;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    if (lines[i].cols() < 2) {
      throw std::runtime_error(path + ": cannot save polyline " + std::to_string(i) + " with fewer than 2 points");
    }
    if (!lines[i].allFinite()) throw std::runtime_error(path + ": polyline " + std::to_string(i) + " has non-finite points");
    point_count += lines[i].cols();
  }
  if (decimals > 0) return writePolylinesAscii(path, lines, title, decimals);
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(point_count);
  vtkNew<vtkCellArray> cells;
  vtkIdType next = 0;
  for (const Polyline& line : lines) {
    cells->InsertNextCell(line.cols());
    for (Eigen::Index i = 0; i < line.cols(); ++i) {
      points->SetPoint(next, line(0, i), line(1, i), line(2, i));
      cells->InsertCellPoint(next++);
    }
  }
  vtkNew<vtkPolyData> data;
  data->SetPoints(points);
  data->SetLines(cells);
  vtkNew<vtkPolyDataWriter> writer;
  writer->SetFileName(path.c_str());
  writer->SetInputData(data);
  writer->SetHeader(title.c_str());
  // Binary: VTK 9.1 writes ASCII doubles with 11 significant digits, which would not read back exactly.
  writer->SetFileTypeToBinary();
  writer->SetFileVersion(vtkDataWriter::VTK_LEGACY_READER_VERSION_4_2);  // readable by VTK before 9 too
  write(path, writer);
}

std::string recordedFibreCheckFailures(const std::string& path) {
  std::ifstream in(path);
  std::string first, title;
  if (!std::getline(in, first) || first.rfind("# vtk DataFile", 0) != 0 || !std::getline(in, title)) return "";
  const std::size_t mark = title.find(kFibreChecksFailedMark);
  if (mark == std::string::npos) return "";
  std::string failures = title.substr(mark + std::strlen(kFibreChecksFailedMark));
  while (!failures.empty() && std::isspace(static_cast<unsigned char>(failures.back()))) failures.pop_back();
  return failures;
}

void saveTriangleMeshStl(const std::string& path, const TriangleMesh& mesh) {
  const Eigen::Index n = mesh.vertexCount();
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    for (int k = 0; k < 3; ++k) {
      if (mesh.triangles(k, t) < 0 || mesh.triangles(k, t) >= n) {
        throw std::runtime_error(path + ": triangle " + std::to_string(t) + " has an out-of-range vertex index");
      }
    }
  }
  vtkNew<vtkSTLWriter> writer;
  writer->SetFileName(path.c_str());
  writer->SetInputData(toPolyData(mesh));
  writer->SetFileTypeToBinary();
  writer->SetHeader("binary STL written by muscle_deformation");  // must not start with "solid"
  write(path, writer);
}

}  // namespace muscle_deformation
