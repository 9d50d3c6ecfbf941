// Loaders for STL, legacy VTK, VTK XML PolyData (.vtp) and Wavefront OBJ, plus two small writers.
// Self-contained on purpose (Eigen + zlib only): the core must build without ROS, VTK or PCL.
#include "muscle_deformation/core/io/mesh_io.hpp"

#include <zlib.h>

#include <algorithm>
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
#include <iomanip>
#include <limits>
#include <sstream>
#include <string_view>
#include <unordered_map>
#include <utility>
#include <vector>

namespace muscle_deformation {

namespace {

// ---------------------------------------------------------------------------------------------------------------
// Errors

[[noreturn]] void fail(const std::string& path, const std::string& msg) { throw LoadError(path + ": " + msg); }

[[noreturn]] void failAtLine(const std::string& path, long line, const std::string& msg) {
  throw LoadError(path + " line " + std::to_string(line) + ": " + msg);
}

[[noreturn]] void failAtByte(const std::string& path, std::size_t offset, const std::string& msg) {
  throw LoadError(path + " byte offset " + std::to_string(offset) + ": " + msg);
}

// A token as it appears in messages: quoted, shortened so binary garbage cannot flood the terminal.
std::string quoted(std::string_view token) {
  std::string out = "'";
  for (char ch : token.substr(0, 40)) out += std::isprint(static_cast<unsigned char>(ch)) ? ch : '?';
  if (token.size() > 40) out += "...";
  return out + "'";
}

// ---------------------------------------------------------------------------------------------------------------
// Files, names and numbers

std::string readWholeFile(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) fail(path, "file not found");
  if (std::filesystem::is_directory(path, ec)) fail(path, "is a directory, not a mesh file");
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, std::string("cannot open file: ") + std::strerror(errno));
  std::ostringstream content;
  content << in.rdbuf();
  if (in.bad()) fail(path, "read error");
  return content.str();
}

std::string lowerExtension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& ch : ext) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  return ext;
}

bool equalsIgnoreCase(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (std::tolower(static_cast<unsigned char>(a[i])) != std::tolower(static_cast<unsigned char>(b[i]))) return false;
  }
  return true;
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

// Binary numbers in a given byte order, independent of the host's.
template <typename T>
T readBinary(const char* p, bool big_endian) {
  static_assert(sizeof(T) <= 8, "scalar types only");
  unsigned char bytes[sizeof(T)];
  std::memcpy(bytes, p, sizeof(T));
  const std::uint16_t probe = 1;
  const bool host_little = *reinterpret_cast<const unsigned char*>(&probe) == 1;
  if (host_little == big_endian) std::reverse(bytes, bytes + sizeof(T));
  T value;
  std::memcpy(&value, bytes, sizeof(T));
  return value;
}

// ---------------------------------------------------------------------------------------------------------------
// Whitespace-separated tokens with line numbers.

class TextScanner {
 public:
  explicit TextScanner(std::string_view text, std::size_t pos = 0, long line = 1) : text_(text), pos_(pos), line_(line) {}

  // Next token, or false at the end of the text. token_line() is the line it starts on.
  bool next(std::string_view& token) {
    skipSpace();
    if (pos_ >= text_.size()) return false;
    const std::size_t start = pos_;
    while (pos_ < text_.size() && !isSpace(text_[pos_])) ++pos_;
    token = text_.substr(start, pos_ - start);
    token_line_ = line_;
    token_pos_ = start;
    return true;
  }

  // The remainder of the current line (without the newline); moves to the start of the next line.
  std::string_view restOfLine() {
    const std::size_t start = pos_;
    while (pos_ < text_.size() && text_[pos_] != '\n') ++pos_;
    std::string_view rest = text_.substr(start, pos_ - start);
    if (pos_ < text_.size()) {
      ++pos_;
      ++line_;
    }
    while (!rest.empty() && (rest.back() == '\r' || rest.back() == ' ' || rest.back() == '\t')) rest.remove_suffix(1);
    while (!rest.empty() && (rest.front() == ' ' || rest.front() == '\t')) rest.remove_prefix(1);
    return rest;
  }

  bool atEnd() {
    skipSpace();
    return pos_ >= text_.size();
  }

  // Peeks at the next token without consuming it.
  std::string_view peek() {
    TextScanner copy = *this;
    std::string_view token;
    return copy.next(token) ? token : std::string_view();
  }

  long tokenLine() const { return token_line_; }
  std::size_t tokenPos() const { return token_pos_; }
  long line() const { return line_; }
  std::size_t pos() const { return pos_; }
  void skipBytes(std::size_t n) { pos_ += n; }  // binary payloads: line counting stops meaning anything
  std::size_t remaining() const { return pos_ < text_.size() ? text_.size() - pos_ : 0; }

 private:
  static bool isSpace(char ch) { return ch == ' ' || ch == '\t' || ch == '\n' || ch == '\r' || ch == '\f' || ch == '\v'; }
  void skipSpace() {
    while (pos_ < text_.size() && isSpace(text_[pos_])) {
      if (text_[pos_] == '\n') ++line_;
      ++pos_;
    }
  }

  std::string_view text_;
  std::size_t pos_;
  long line_;
  long token_line_ = 0;
  std::size_t token_pos_ = 0;
};

// ---------------------------------------------------------------------------------------------------------------
// Intermediate geometry shared by the VTK, VTP and OBJ readers.

struct CellList {
  std::vector<std::int64_t> offsets{0};  // cell i is connectivity[offsets[i], offsets[i+1])
  std::vector<std::int64_t> connectivity;
  std::size_t size() const { return offsets.size() - 1; }
  void append(const CellList& other, std::int64_t index_shift) {
    const std::int64_t base = static_cast<std::int64_t>(connectivity.size());
    for (std::size_t i = 1; i < other.offsets.size(); ++i) offsets.push_back(base + other.offsets[i]);
    for (std::int64_t v : other.connectivity) connectivity.push_back(v + index_shift);
  }
};

struct PolyData {
  std::vector<double> xyz;  // 3 per point
  CellList polys;
  CellList strips;
  CellList lines;
  std::size_t pointCount() const { return xyz.size() / 3; }
};

Vertices toVertices(const std::vector<double>& xyz, double scale) {
  Vertices v(3, static_cast<Eigen::Index>(xyz.size() / 3));
  for (Eigen::Index i = 0; i < v.cols(); ++i) {
    for (int k = 0; k < 3; ++k) v(k, i) = xyz[static_cast<std::size_t>(3 * i + k)] * scale;
  }
  return v;
}

// Final index check for formats where the cells could not be checked while reading.
void checkCellIndices(const std::string& path, const CellList& cells, std::size_t points, const char* section) {
  for (std::size_t c = 0; c < cells.size(); ++c) {
    for (auto i = cells.offsets[c]; i < cells.offsets[c + 1]; ++i) {
      const std::int64_t v = cells.connectivity[static_cast<std::size_t>(i)];
      if (v < 0 || static_cast<std::size_t>(v) >= points) {
        fail(path, std::string(section) + " cell " + std::to_string(c) + " refers to point " + std::to_string(v) +
                       " but there are only " + std::to_string(points) + " points (valid: 0 to " +
                       std::to_string(static_cast<long long>(points) - 1) + ")");
      }
    }
  }
}

TriangleMesh trianglesFromPolyData(const std::string& path, const PolyData& data, double scale) {
  std::vector<int> tri;
  for (std::size_t c = 0; c < data.polys.size(); ++c) {
    const auto begin = data.polys.offsets[c];
    const auto count = data.polys.offsets[c + 1] - begin;
    if (count < 3) {
      fail(path, "polygon " + std::to_string(c) + " has " + std::to_string(count) + " vertices; at least 3 are needed");
    }
    // Fan from the first vertex: exact for the convex polygons mesh tools write, and keeps the winding.
    for (std::int64_t k = 1; k + 1 < count; ++k) {
      tri.push_back(static_cast<int>(data.polys.connectivity[begin]));
      tri.push_back(static_cast<int>(data.polys.connectivity[begin + k]));
      tri.push_back(static_cast<int>(data.polys.connectivity[begin + k + 1]));
    }
  }
  for (std::size_t c = 0; c < data.strips.size(); ++c) {
    const auto begin = data.strips.offsets[c];
    const auto count = data.strips.offsets[c + 1] - begin;
    if (count < 3) {
      fail(path, "triangle strip " + std::to_string(c) + " has " + std::to_string(count) + " vertices; at least 3 are needed");
    }
    for (std::int64_t k = 0; k + 2 < count; ++k) {
      // Every other triangle of a strip is wound backwards; swap two corners to keep the orientation.
      const auto* s = &data.strips.connectivity[static_cast<std::size_t>(begin + k)];
      const bool odd = (k % 2) == 1;
      tri.push_back(static_cast<int>(s[0]));
      tri.push_back(static_cast<int>(odd ? s[2] : s[1]));
      tri.push_back(static_cast<int>(odd ? s[1] : s[2]));
    }
  }
  if (tri.empty()) {
    if (data.lines.size() > 0) {
      fail(path, "contains no triangles, only " + std::to_string(data.lines.size()) +
                     " lines (is this a fibre file? read it with loadPolylines)");
    }
    fail(path, "contains no triangles");
  }
  TriangleMesh mesh;
  mesh.vertices = toVertices(data.xyz, scale);
  mesh.triangles = Eigen::Map<const Triangles>(tri.data(), 3, static_cast<Eigen::Index>(tri.size() / 3));
  return mesh;
}

std::vector<Polyline> polylinesFromPolyData(const std::string& path, const PolyData& data, double scale) {
  if (data.lines.size() == 0) {
    if (data.polys.size() > 0 || data.strips.size() > 0) {
      fail(path, "contains no lines, only surface polygons (is this a surface file? read it with loadTriangleMesh)");
    }
    fail(path, "contains no lines");
  }
  std::vector<Polyline> lines;
  lines.reserve(data.lines.size());
  for (std::size_t c = 0; c < data.lines.size(); ++c) {
    const auto begin = data.lines.offsets[c];
    const auto count = data.lines.offsets[c + 1] - begin;
    // A line of fewer than 2 points is kept: the model skips it with a warning, as it skips a zero-length or
    // non-finite one (one rule for every degenerate fibre, applied where fibres are used).
    Polyline line(3, count);
    for (std::int64_t k = 0; k < count; ++k) {
      const auto p = static_cast<std::size_t>(data.lines.connectivity[static_cast<std::size_t>(begin + k)]);
      for (int d = 0; d < 3; ++d) line(d, k) = data.xyz[3 * p + static_cast<std::size_t>(d)] * scale;
    }
    lines.push_back(std::move(line));
  }
  return lines;
}

// ---------------------------------------------------------------------------------------------------------------
// STL

// Merges exactly equal coordinates into one vertex, keeping first-appearance order.
class VertexWelder {
 public:
  int add(double x, double y, double z) {
    // +0 and -0 compare equal, so they must hash equally.
    const Key key{{x == 0.0 ? 0.0 : x, y == 0.0 ? 0.0 : y, z == 0.0 ? 0.0 : z}};
    const auto inserted = index_.emplace(key, static_cast<int>(xyz_.size() / 3));
    if (inserted.second) {
      xyz_.push_back(key.c[0]);
      xyz_.push_back(key.c[1]);
      xyz_.push_back(key.c[2]);
    }
    return inserted.first->second;
  }
  const std::vector<double>& xyz() const { return xyz_; }

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
  std::vector<double> xyz_;
};

TriangleMesh meshFromWelded(const VertexWelder& welder, const std::vector<int>& tri, double scale) {
  TriangleMesh mesh;
  mesh.vertices = toVertices(welder.xyz(), scale);
  mesh.triangles = Eigen::Map<const Triangles>(tri.data(), 3, static_cast<Eigen::Index>(tri.size() / 3));
  return mesh;
}

TriangleMesh readBinaryStl(const std::string& path, const std::string& data, double scale) {
  const auto n = readBinary<std::uint32_t>(data.data() + 80, false);
  VertexWelder welder;
  std::vector<int> tri;
  tri.reserve(3 * static_cast<std::size_t>(n));
  for (std::uint32_t t = 0; t < n; ++t) {
    const std::size_t record = 84 + 50 * static_cast<std::size_t>(t);
    for (int v = 0; v < 3; ++v) {
      double c[3];
      for (int k = 0; k < 3; ++k) {
        const std::size_t at = record + 12 + 12 * static_cast<std::size_t>(v) + 4 * static_cast<std::size_t>(k);
        c[k] = readBinary<float>(data.data() + at, false);
        if (!std::isfinite(c[k])) {
          failAtByte(path, at, "triangle " + std::to_string(t) + " has a NaN or infinite vertex coordinate");
        }
      }
      tri.push_back(welder.add(c[0], c[1], c[2]));
    }
  }
  return meshFromWelded(welder, tri, scale);
}

TriangleMesh readAsciiStl(const std::string& path, const std::string& data, double scale) {
  TextScanner sc(data);
  std::string_view tok;
  VertexWelder welder;
  std::vector<int> tri;
  auto expect = [&](std::string_view word, const char* context) {
    if (!sc.next(tok)) fail(path, std::string("unexpected end of file ") + context + ": expected '" + std::string(word) + "'");
    if (!equalsIgnoreCase(tok, word)) {
      failAtLine(path, sc.tokenLine(), "expected '" + std::string(word) + "' " + context + ", found " + quoted(tok));
    }
  };
  auto number = [&](const char* what) {
    if (!sc.next(tok)) fail(path, std::string("unexpected end of file while reading ") + what);
    double value;
    if (!parseDouble(tok, value)) {
      failAtLine(path, sc.tokenLine(), std::string("expected a number for ") + what + ", found " + quoted(tok));
    }
    return value;
  };

  bool in_solid = false;
  while (sc.next(tok)) {
    if (equalsIgnoreCase(tok, "solid")) {
      if (in_solid) failAtLine(path, sc.tokenLine(), "'solid' inside another solid (missing 'endsolid')");
      in_solid = true;
      sc.restOfLine();  // the solid's name
    } else if (equalsIgnoreCase(tok, "endsolid")) {
      if (!in_solid) failAtLine(path, sc.tokenLine(), "'endsolid' without a matching 'solid'");
      in_solid = false;
      sc.restOfLine();
    } else if (equalsIgnoreCase(tok, "facet")) {
      if (!in_solid) failAtLine(path, sc.tokenLine(), "'facet' outside 'solid ... endsolid'");
      const long facet_line = sc.tokenLine();
      expect("normal", "after 'facet'");
      for (int k = 0; k < 3; ++k) number("the facet normal");  // recomputed from the winding when needed
      expect("outer", "after the facet normal");
      expect("loop", "after 'outer'");
      int corners = 0;
      while (true) {
        if (!sc.next(tok)) fail(path, "unexpected end of file inside the facet starting on line " + std::to_string(facet_line));
        if (equalsIgnoreCase(tok, "endloop")) break;
        if (!equalsIgnoreCase(tok, "vertex")) {
          failAtLine(path, sc.tokenLine(), "expected 'vertex' or 'endloop', found " + quoted(tok));
        }
        const long vertex_line = sc.tokenLine();
        double c[3];
        for (int k = 0; k < 3; ++k) {
          if (!sc.next(tok)) fail(path, "unexpected end of file inside the vertex on line " + std::to_string(vertex_line));
          if (!parseDouble(tok, c[k])) {
            if (sc.tokenLine() != vertex_line) {  // the vertex line itself is short
              failAtLine(path, vertex_line, "expected 3 coordinates per vertex, found " + std::to_string(k));
            }
            failAtLine(path, sc.tokenLine(), "expected a number for a vertex coordinate, found " + quoted(tok));
          }
          if (!std::isfinite(c[k])) failAtLine(path, sc.tokenLine(), "vertex coordinate " + quoted(tok) + " is not finite");
        }
        if (++corners > 3) {
          failAtLine(path, vertex_line, "facet starting on line " + std::to_string(facet_line) +
                                            " has more than 3 vertices; STL facets must be triangles");
        }
        tri.push_back(welder.add(c[0], c[1], c[2]));
      }
      if (corners != 3) {
        failAtLine(path, sc.tokenLine(), "facet starting on line " + std::to_string(facet_line) + " has " +
                                             std::to_string(corners) + " vertices; STL facets must have exactly 3");
      }
      expect("endfacet", "after 'endloop'");
    } else {
      failAtLine(path, sc.tokenLine(), "expected 'facet' or 'endsolid', found " + quoted(tok));
    }
  }
  if (in_solid) fail(path, "unexpected end of file: missing 'endsolid' (truncated file?)");
  if (tri.empty()) fail(path, "contains no triangles (no 'facet' records)");
  return meshFromWelded(welder, tri, scale);
}

TriangleMesh readStl(const std::string& path, double scale) {
  const std::string data = readWholeFile(path);
  if (data.empty()) fail(path, "file is empty");
  // The size rule is decisive: some binary writers start the 80-byte header with "solid" too.
  if (data.size() >= 84) {
    const auto n = readBinary<std::uint32_t>(data.data() + 80, false);
    const std::uint64_t expected = 84 + 50 * static_cast<std::uint64_t>(n);
    if (expected == data.size()) {
      if (n == 0) fail(path, "binary STL contains no triangles");
      return readBinaryStl(path, data, scale);
    }
  }
  std::size_t first = 0;
  while (first < data.size() && std::isspace(static_cast<unsigned char>(data[first]))) ++first;
  const bool starts_with_solid = data.size() - first >= 5 && equalsIgnoreCase(std::string_view(data).substr(first, 5), "solid");
  if (starts_with_solid && std::memchr(data.data(), '\0', data.size()) == nullptr) return readAsciiStl(path, data, scale);
  if (data.size() < 84) {
    fail(path, "too short for a binary STL (" + std::to_string(data.size()) +
                   " bytes, the header alone is 84) and not an ASCII STL (does not start with 'solid')");
  }
  const auto n = readBinary<std::uint32_t>(data.data() + 80, false);
  fail(path, "truncated or corrupt binary STL: header declares " + std::to_string(n) + " triangles, which needs " +
                 std::to_string(84 + 50 * static_cast<std::uint64_t>(n)) + " bytes, but the file has " +
                 std::to_string(data.size()) + " bytes");
}

// ---------------------------------------------------------------------------------------------------------------
// Legacy VTK (POLYDATA)

struct VtkType {
  std::size_t size;
  bool floating;
  bool is_signed;
};

bool vtkTypeFromName(std::string_view name, VtkType& type) {
  static const std::pair<const char*, VtkType> table[] = {
      {"float", {4, true, true}},          {"double", {8, true, true}},
      {"char", {1, false, true}},          {"unsigned_char", {1, false, false}},
      {"short", {2, false, true}},         {"unsigned_short", {2, false, false}},
      {"int", {4, false, true}},           {"unsigned_int", {4, false, false}},
      {"long", {8, false, true}},          {"unsigned_long", {8, false, false}},
      {"vtkidtype", {8, false, true}},     {"vtktypeint64", {8, false, true}},
      {"vtktypeuint64", {8, false, false}}, {"vtktypeint32", {4, false, true}},
      {"vtktypeuint32", {4, false, false}}};
  for (const auto& entry : table) {
    if (equalsIgnoreCase(name, entry.first)) {
      type = entry.second;
      return true;
    }
  }
  return false;
}

double decodeBinaryNumber(const char* p, const VtkType& type, bool big_endian) {
  if (type.floating) return type.size == 4 ? readBinary<float>(p, big_endian) : readBinary<double>(p, big_endian);
  switch (type.size) {
    case 1:
      return type.is_signed ? static_cast<double>(static_cast<signed char>(*p)) : static_cast<double>(static_cast<unsigned char>(*p));
    case 2:
      return type.is_signed ? readBinary<std::int16_t>(p, big_endian) : readBinary<std::uint16_t>(p, big_endian);
    case 4:
      return type.is_signed ? readBinary<std::int32_t>(p, big_endian) : readBinary<std::uint32_t>(p, big_endian);
    default:
      return type.is_signed ? static_cast<double>(readBinary<std::int64_t>(p, big_endian))
                            : static_cast<double>(readBinary<std::uint64_t>(p, big_endian));
  }
}

class LegacyVtkReader {
 public:
  LegacyVtkReader(const std::string& path, const std::string& data) : path_(path), data_(data), sc_(data) {}

  PolyData read() {
    readHeader();
    std::string_view tok;
    if (!sc_.next(tok)) fail(path_, "unexpected end of file: expected 'DATASET POLYDATA'");
    while (equalsIgnoreCase(tok, "FIELD")) {  // field data may precede the dataset
      skipField();
      if (!sc_.next(tok)) fail(path_, "unexpected end of file: expected 'DATASET POLYDATA'");
    }
    if (!equalsIgnoreCase(tok, "DATASET")) failHere("expected 'DATASET POLYDATA', found " + quoted(tok));
    if (!sc_.next(tok)) fail(path_, "unexpected end of file after 'DATASET'");
    if (!equalsIgnoreCase(tok, "POLYDATA")) {
      failHere("only 'DATASET POLYDATA' is supported, found 'DATASET " + std::string(tok) + "'");
    }
    bool have_points = false;
    while (sc_.next(tok)) {
      if (equalsIgnoreCase(tok, "POINTS")) {
        readPoints();
        have_points = true;
      } else if (equalsIgnoreCase(tok, "POLYGONS")) {
        readCells(result_.polys, "POLYGONS");
      } else if (equalsIgnoreCase(tok, "TRIANGLE_STRIPS")) {
        readCells(result_.strips, "TRIANGLE_STRIPS");
      } else if (equalsIgnoreCase(tok, "LINES")) {
        readCells(result_.lines, "LINES");
      } else if (equalsIgnoreCase(tok, "VERTICES")) {
        CellList ignored;
        readCells(ignored, "VERTICES");
      } else if (equalsIgnoreCase(tok, "FIELD")) {
        skipField();
      } else if (equalsIgnoreCase(tok, "METADATA")) {
        skipMetadata();
      } else if (equalsIgnoreCase(tok, "POINT_DATA") || equalsIgnoreCase(tok, "CELL_DATA")) {
        break;  // attributes always follow the geometry and carry nothing we need
      } else {
        failHere("unexpected " + quoted(tok) +
                 "; expected a section keyword (POINTS, POLYGONS, LINES, VERTICES, TRIANGLE_STRIPS, POINT_DATA, "
                 "CELL_DATA)");
      }
    }
    if (!have_points) fail(path_, "has no POINTS section");
    checkCellIndices(path_, result_.polys, result_.pointCount(), "POLYGONS");
    checkCellIndices(path_, result_.strips, result_.pointCount(), "TRIANGLE_STRIPS");
    checkCellIndices(path_, result_.lines, result_.pointCount(), "LINES");
    return std::move(result_);
  }

 private:
  // Binary files mix text and bytes, so after the header a byte offset is the only location that means anything.
  [[noreturn]] void failHere(const std::string& msg) {
    if (binary_) failAtByte(path_, sc_.tokenPos(), msg);
    failAtLine(path_, sc_.tokenLine(), msg);
  }

  void readHeader() {
    const std::string_view first = sc_.restOfLine();
    std::string lowered(first);
    for (char& ch : lowered) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    if (lowered.rfind('#', 0) != 0 || lowered.find("vtk") == std::string::npos || lowered.find("datafile") == std::string::npos) {
      failAtLine(path_, 1, "not a legacy VTK file: the first line must be '# vtk DataFile Version x.y', found " + quoted(first));
    }
    sc_.restOfLine();  // title: free text
    const long format_line = sc_.line();
    const std::string_view format = sc_.restOfLine();
    if (equalsIgnoreCase(format, "ASCII")) {
      binary_ = false;
    } else if (equalsIgnoreCase(format, "BINARY")) {
      binary_ = true;
    } else {
      failAtLine(path_, format_line, "expected 'ASCII' or 'BINARY' on line 3, found " + quoted(format));
    }
  }

  // Counts are bounded by the file size so that a corrupt count cannot trigger a huge allocation.
  std::size_t readCount(const std::string& what) {
    std::string_view tok;
    if (!sc_.next(tok)) fail(path_, "unexpected end of file: expected " + what);
    long long value;
    if (!parseInt(tok, value) || value < 0) failHere("expected " + what + " (a non-negative integer), found " + quoted(tok));
    if (static_cast<unsigned long long>(value) > data_.size()) {
      failHere(what + " is " + std::to_string(value) + ", more than a file of " + std::to_string(data_.size()) +
               " bytes can hold (corrupt or truncated file?)");
    }
    return static_cast<std::size_t>(value);
  }

  VtkType readType(const std::string& section) {
    std::string_view tok;
    if (!sc_.next(tok)) fail(path_, "unexpected end of file: expected the data type of " + section);
    VtkType type;
    if (!vtkTypeFromName(tok, type)) failHere("unknown data type " + quoted(tok) + " for " + section);
    return type;
  }

  // BINARY payloads start right after the newline that ends their keyword line; the caller consumes that line.
  const char* takeBytes(std::size_t bytes, const std::string& what) {
    if (sc_.remaining() < bytes) {
      failAtByte(path_, sc_.pos(), "file ends inside the binary data of " + what + " (needs " + std::to_string(bytes) +
                                       " bytes, only " + std::to_string(sc_.remaining()) + " left): truncated file?");
    }
    const char* p = data_.data() + sc_.pos();
    sc_.skipBytes(bytes);
    return p;
  }

  // ASCII numbers; remembers how many numbers each line held to pinpoint a line with a missing coordinate.
  void readAsciiPoints(std::size_t count, std::vector<double>& out, const std::string& what) {
    std::vector<std::pair<long, int>> per_line;
    std::string_view tok;
    for (std::size_t i = 0; i < count; ++i) {
      if (!sc_.next(tok)) {
        fail(path_, "unexpected end of file in " + what + ": expected " + std::to_string(count) + " coordinates, found " +
                        std::to_string(i));
      }
      double value;
      if (!parseDouble(tok, value)) {
        // A finished line holding a partial point explains the shortfall better than the token that exposed it.
        for (const auto& entry : per_line) {
          if (entry.second % 3 != 0 && entry.first != sc_.tokenLine()) {
            failAtLine(path_, entry.first, "expected 3 coordinates per point, found " + std::to_string(entry.second % 3) +
                                               " (" + what + " needs " + std::to_string(count) + " numbers, but only " +
                                               std::to_string(i) + " precede " + quoted(tok) + " on line " +
                                               std::to_string(sc_.tokenLine()) + ")");
          }
        }
        failAtLine(path_, sc_.tokenLine(), "expected a coordinate in " + what + ", found " + quoted(tok) + " (" +
                                               std::to_string(i) + " of " + std::to_string(count) + " numbers read)");
      }
      if (!std::isfinite(value)) failAtLine(path_, sc_.tokenLine(), "coordinate " + quoted(tok) + " is not finite");
      if (per_line.empty() || per_line.back().first != sc_.tokenLine()) per_line.emplace_back(sc_.tokenLine(), 0);
      ++per_line.back().second;
      out.push_back(value);
    }
  }

  void readPoints() {
    const std::size_t n = readCount("the number of points after POINTS");
    const VtkType type = readType("POINTS");
    if (!result_.xyz.empty()) failHere("a second POINTS section; only one is allowed");
    const std::string what = "POINTS (" + std::to_string(n) + " points)";
    const std::size_t count = 3 * n;
    result_.xyz.reserve(count);
    if (!binary_) {
      readAsciiPoints(count, result_.xyz, what);
      return;
    }
    sc_.restOfLine();
    const char* p = takeBytes(count * type.size, what);
    for (std::size_t i = 0; i < count; ++i) {
      const double value = decodeBinaryNumber(p + i * type.size, type, true);
      if (!std::isfinite(value)) {
        failAtByte(path_, static_cast<std::size_t>(p - data_.data()) + i * type.size,
                   "point " + std::to_string(i / 3) + " has a NaN or infinite coordinate");
      }
      result_.xyz.push_back(value);
    }
  }

  // Reads `count` integers. In BINARY files the keyword line must already be consumed.
  std::vector<std::int64_t> readIntegers(std::size_t count, const VtkType& type, const std::string& what) {
    std::vector<std::int64_t> values;
    values.reserve(count);
    index_lines_.clear();
    if (binary_) {
      if (type.floating) failHere(what + " must be integers, not floating point");
      const char* p = takeBytes(count * type.size, what);
      for (std::size_t i = 0; i < count; ++i) {
        const double value = decodeBinaryNumber(p + i * type.size, type, true);
        if (!(std::abs(value) < 9.0e15)) {
          failAtByte(path_, static_cast<std::size_t>(p - data_.data()) + i * type.size, what + " holds an out-of-range integer");
        }
        values.push_back(static_cast<std::int64_t>(value));
      }
      return values;
    }
    std::string_view tok;
    for (std::size_t i = 0; i < count; ++i) {
      if (!sc_.next(tok)) {
        fail(path_, "unexpected end of file in " + what + ": expected " + std::to_string(count) + " integers, found " +
                        std::to_string(i));
      }
      long long value;
      if (!parseInt(tok, value)) {
        failAtLine(path_, sc_.tokenLine(), "expected an integer in " + what + ", found " + quoted(tok) + " (" +
                                               std::to_string(i) + " of " + std::to_string(count) + " read)");
      }
      values.push_back(value);
      index_lines_.push_back(sc_.tokenLine());
    }
    return values;
  }

  [[noreturn]] void failAtInteger(std::size_t at, const std::string& msg) {
    if (!binary_ && at < index_lines_.size()) failAtLine(path_, index_lines_[at], msg);
    failHere(msg);
  }

  void checkIndexNow(std::int64_t index, std::size_t at, const std::string& section) {
    const std::size_t points = result_.pointCount();
    if (index >= 0 && static_cast<std::size_t>(index) < points) return;
    failAtInteger(at, section + " refers to point " + std::to_string(index) + " but POINTS declares only " +
                          std::to_string(points) + " points (valid: 0 to " +
                          std::to_string(static_cast<long long>(points) - 1) + ")");
  }

  void readCells(CellList& cells, const std::string& section) {
    const std::size_t n = readCount("the number of cells after " + section);
    const std::size_t size = readCount("the list size after " + section);
    const bool points_known = !result_.xyz.empty();

    // VTK 9 ("# vtk DataFile Version 5.1") writes OFFSETS and CONNECTIVITY arrays instead of size-prefixed cells.
    bool new_layout;
    if (binary_) {
      sc_.restOfLine();
      new_layout = data_.compare(sc_.pos(), 7, "OFFSETS") == 0;
    } else {
      new_layout = equalsIgnoreCase(sc_.peek(), "OFFSETS");
    }

    if (new_layout) {
      std::string_view tok;
      sc_.next(tok);  // OFFSETS
      const VtkType offset_type = readType(section + " OFFSETS");
      if (binary_) sc_.restOfLine();
      const auto offsets = readIntegers(n, offset_type, section + " OFFSETS");
      if (!sc_.next(tok) || !equalsIgnoreCase(tok, "CONNECTIVITY")) failHere("expected CONNECTIVITY after the OFFSETS of " + section);
      const VtkType conn_type = readType(section + " CONNECTIVITY");
      if (binary_) sc_.restOfLine();
      const auto conn = readIntegers(size, conn_type, section + " CONNECTIVITY");
      if (n == 0 || offsets.front() != 0 || offsets.back() != static_cast<std::int64_t>(size)) {
        failHere(section + " OFFSETS must start at 0 and end at the connectivity size " + std::to_string(size));
      }
      for (std::size_t i = 1; i < offsets.size(); ++i) {
        if (offsets[i] < offsets[i - 1]) failHere(section + " OFFSETS must not decrease");
        cells.offsets.push_back(offsets[i]);
      }
      for (std::size_t i = 0; i < conn.size(); ++i) {
        if (points_known) checkIndexNow(conn[i], i, section);
        cells.connectivity.push_back(conn[i]);
      }
      return;
    }

    const auto list = readIntegers(size, VtkType{4, false, true}, section);
    std::size_t at = 0;
    for (std::size_t c = 0; c < n; ++c) {
      if (at >= list.size()) {
        failHere(section + " declares " + std::to_string(n) + " cells in " + std::to_string(size) +
                 " numbers, but the numbers run out at cell " + std::to_string(c));
      }
      const std::int64_t count = list[at];
      if (count < 0 || static_cast<std::size_t>(count) > list.size() - at - 1) {
        failAtInteger(at, section + " cell " + std::to_string(c) + " claims " + std::to_string(count) +
                              " points, which does not fit the declared list size " + std::to_string(size));
      }
      for (std::int64_t k = 0; k < count; ++k) {
        const std::size_t i = at + 1 + static_cast<std::size_t>(k);
        if (points_known) checkIndexNow(list[i], i, section);
        cells.connectivity.push_back(list[i]);
      }
      cells.offsets.push_back(static_cast<std::int64_t>(cells.connectivity.size()));
      at += 1 + static_cast<std::size_t>(count);
    }
    if (at != list.size()) {
      failHere(section + " declares a list size of " + std::to_string(size) + " but its " + std::to_string(n) +
               " cells use " + std::to_string(at) + " numbers");
    }
  }

  // FIELD name n, then n arrays "name components tuples type" with their values.
  void skipField() {
    std::string_view tok;
    if (!sc_.next(tok)) fail(path_, "unexpected end of file in FIELD");  // field name
    const std::size_t arrays = readCount("the number of arrays after FIELD");
    for (std::size_t a = 0; a < arrays; ++a) {
      if (!sc_.next(tok)) fail(path_, "unexpected end of file in FIELD");
      const std::string name(tok);
      const std::size_t components = readCount("the number of components of a FIELD array");
      const std::size_t tuples = readCount("the number of tuples of a FIELD array");
      std::string_view type_name;
      if (!sc_.next(type_name)) fail(path_, "unexpected end of file in FIELD");
      const std::size_t count = components * tuples;
      VtkType type{1, false, false};
      if (equalsIgnoreCase(type_name, "string")) {
        failHere("FIELD array '" + name + "' holds strings, which this reader cannot skip; remove the field data");
      }
      if (!vtkTypeFromName(type_name, type)) failHere("unknown data type " + quoted(type_name) + " in FIELD array '" + name + "'");
      if (binary_) {
        if (count > data_.size()) failHere("FIELD array '" + name + "' is larger than the file (corrupt file?)");
        sc_.restOfLine();
        takeBytes(count * type.size, "FIELD array '" + name + "'");
      } else {
        for (std::size_t i = 0; i < count; ++i) {
          if (!sc_.next(tok)) fail(path_, "unexpected end of file in FIELD array '" + name + "'");
        }
      }
      if (equalsIgnoreCase(sc_.peek(), "METADATA")) {
        sc_.next(tok);
        skipMetadata();
      }
    }
  }

  // METADATA blocks (VTK 8+) are text terminated by an empty line.
  void skipMetadata() {
    sc_.restOfLine();
    while (sc_.remaining() > 0) {
      if (sc_.restOfLine().empty()) break;
    }
  }

  const std::string& path_;
  const std::string& data_;
  TextScanner sc_;
  bool binary_ = false;
  PolyData result_;
  std::vector<long> index_lines_;  // ASCII: line of each integer just read, for precise messages
};

PolyData readLegacyVtk(const std::string& path) {
  const std::string data = readWholeFile(path);
  if (data.empty()) fail(path, "file is empty");
  return LegacyVtkReader(path, data).read();
}

// ---------------------------------------------------------------------------------------------------------------
// VTK XML PolyData (.vtp): a minimal XML reader, enough for what VTK writes.

struct XmlElement {
  std::string name;
  std::vector<std::pair<std::string, std::string>> attributes;
  std::vector<std::size_t> children;
  std::size_t content_begin = 0;  // raw text between the start and end tags
  std::size_t content_end = 0;
  std::size_t offset = 0;  // of the '<'

  const std::string* attribute(std::string_view key) const {
    for (const auto& a : attributes) {
      if (a.first == key) return &a.second;
    }
    return nullptr;
  }
};

class XmlDocument {
 public:
  XmlDocument(const std::string& path, const std::string& text) : path_(path), text_(text) {
    for (std::size_t i = 0; i < text.size(); ++i) {
      if (text[i] == '\n') newlines_.push_back(i);
    }
    parse();
  }

  long lineAt(std::size_t offset) const {
    return 1 + static_cast<long>(std::lower_bound(newlines_.begin(), newlines_.end(), offset) - newlines_.begin());
  }
  const XmlElement& element(std::size_t i) const { return elements_[i]; }
  std::size_t root() const { return 0; }
  std::string_view content(const XmlElement& e) const {
    return std::string_view(text_).substr(e.content_begin, e.content_end - e.content_begin);
  }

  // Children of `parent` with the given tag name.
  std::vector<std::size_t> children(std::size_t parent, std::string_view name) const {
    std::vector<std::size_t> found;
    for (std::size_t c : elements_[parent].children) {
      if (elements_[c].name == name) found.push_back(c);
    }
    return found;
  }

  [[noreturn]] void failAt(std::size_t offset, const std::string& msg) const { failAtLine(path_, lineAt(offset), msg); }

 private:
  void parse() {
    std::vector<std::size_t> open;
    std::size_t pos = 0;
    const std::size_t n = text_.size();
    while (true) {
      pos = text_.find('<', pos);
      if (pos == std::string::npos) break;
      if (text_.compare(pos, 4, "<!--") == 0) {
        pos = skipPast(pos, "-->", "comment");
      } else if (text_.compare(pos, 2, "<?") == 0) {
        pos = skipPast(pos, "?>", "processing instruction");
      } else if (text_.compare(pos, 9, "<![CDATA[") == 0) {
        pos = skipPast(pos, "]]>", "CDATA section");
      } else if (text_.compare(pos, 2, "<!") == 0) {
        pos = skipPast(pos, ">", "declaration");
      } else if (text_.compare(pos, 2, "</") == 0) {
        const std::size_t start = pos;
        pos += 2;
        const std::string name = readName(pos);
        skipSpace(pos);
        if (pos >= n || text_[pos] != '>') failAt(start, "malformed closing tag </" + name);
        ++pos;
        if (open.empty()) failAt(start, "closing tag </" + name + "> without a matching opening tag");
        XmlElement& e = elements_[open.back()];
        if (e.name != name) {
          failAt(start, "closing tag </" + name + "> does not match <" + e.name + "> opened on line " +
                            std::to_string(lineAt(e.offset)));
        }
        e.content_end = start;
        open.pop_back();
      } else {
        const std::size_t start = pos;
        ++pos;
        XmlElement e;
        e.offset = start;
        e.name = readName(pos);
        if (e.name.empty()) failAt(start, "malformed tag: '<' not followed by an element name");
        bool self_closing = false;
        while (true) {
          skipSpace(pos);
          if (pos >= n) failAt(start, "unterminated tag <" + e.name);
          if (text_[pos] == '>') {
            ++pos;
            break;
          }
          if (text_.compare(pos, 2, "/>") == 0) {
            pos += 2;
            self_closing = true;
            break;
          }
          const std::string key = readName(pos);
          skipSpace(pos);
          if (key.empty() || pos >= n || text_[pos] != '=') failAt(pos, "malformed attribute in tag <" + e.name + ">");
          ++pos;
          skipSpace(pos);
          if (pos >= n || (text_[pos] != '"' && text_[pos] != '\'')) {
            failAt(pos, "attribute '" + key + "' of <" + e.name + "> needs a quoted value");
          }
          const char quote = text_[pos];
          const std::size_t end = text_.find(quote, pos + 1);
          if (end == std::string::npos) failAt(pos, "unterminated value of attribute '" + key + "'");
          e.attributes.emplace_back(key, text_.substr(pos + 1, end - pos - 1));
          pos = end + 1;
        }
        e.content_begin = e.content_end = pos;
        const std::size_t index = elements_.size();
        if (!open.empty()) elements_[open.back()].children.push_back(index);
        else if (index != 0) failAt(start, "more than one top-level element");
        const bool appended = e.name == "AppendedData";
        elements_.push_back(std::move(e));
        if (self_closing) continue;
        if (appended) {
          // Raw appended bytes may contain '<': jump straight to the closing tag.
          const std::size_t close = text_.rfind("</AppendedData");
          if (close == std::string::npos || close < pos) failAt(start, "<AppendedData> is never closed (truncated file?)");
          elements_[index].content_end = close;
          const std::size_t gt = text_.find('>', close);
          if (gt == std::string::npos) failAt(close, "unterminated closing tag </AppendedData");
          pos = gt + 1;
          continue;
        }
        open.push_back(index);
      }
    }
    if (!open.empty()) {
      failAt(elements_[open.back()].offset,
             "<" + elements_[open.back()].name + "> is never closed (truncated file?)");
    }
    if (elements_.empty()) fail(path_, "no XML elements found: not a VTK XML file");
  }

  std::size_t skipPast(std::size_t pos, const char* terminator, const char* what) const {
    const std::size_t end = text_.find(terminator, pos);
    if (end == std::string::npos) failAt(pos, std::string("unterminated ") + what);
    return end + std::strlen(terminator);
  }
  void skipSpace(std::size_t& pos) const {
    while (pos < text_.size() && std::isspace(static_cast<unsigned char>(text_[pos]))) ++pos;
  }
  std::string readName(std::size_t& pos) const {
    const std::size_t start = pos;
    while (pos < text_.size()) {
      const char ch = text_[pos];
      if (std::isalnum(static_cast<unsigned char>(ch)) || ch == '_' || ch == ':' || ch == '-' || ch == '.') {
        ++pos;
      } else {
        break;
      }
    }
    return text_.substr(start, pos - start);
  }

  const std::string& path_;
  const std::string& text_;
  std::vector<std::size_t> newlines_;
  std::vector<XmlElement> elements_;
};

// Base64 that tolerates '=' padding in the middle: VTK encodes the block header and the data separately.
bool decodeBase64(std::string_view text, std::string& out) {
  auto value = [](char ch) -> int {
    if (ch >= 'A' && ch <= 'Z') return ch - 'A';
    if (ch >= 'a' && ch <= 'z') return ch - 'a' + 26;
    if (ch >= '0' && ch <= '9') return ch - '0' + 52;
    if (ch == '+') return 62;
    if (ch == '/') return 63;
    return -1;
  };
  char group[4];
  int filled = 0;
  for (char ch : text) {
    if (std::isspace(static_cast<unsigned char>(ch))) continue;
    if (ch != '=' && value(ch) < 0) return false;
    group[filled++] = ch;
    if (filled < 4) continue;
    filled = 0;
    if (group[0] == '=' || group[1] == '=') return false;
    const int a = value(group[0]), b = value(group[1]);
    out.push_back(static_cast<char>((a << 2) | (b >> 4)));
    if (group[2] == '=') {
      if (group[3] != '=') return false;
      continue;
    }
    const int c = value(group[2]);
    out.push_back(static_cast<char>(((b & 15) << 4) | (c >> 2)));
    if (group[3] == '=') continue;
    out.push_back(static_cast<char>(((c & 3) << 6) | value(group[3])));
  }
  return filled == 0;
}

class VtpReader {
 public:
  VtpReader(const std::string& path, const std::string& text) : path_(path), text_(text), doc_(path, text) {}

  PolyData read() {
    const XmlElement& root = doc_.element(doc_.root());
    if (root.name != "VTKFile") doc_.failAt(root.offset, "not a VTK XML file: the top element is <" + root.name + ">, expected <VTKFile>");
    const std::string* type = root.attribute("type");
    if (type == nullptr || *type != "PolyData") {
      doc_.failAt(root.offset, "VTKFile type is '" + (type ? *type : std::string("(missing)")) +
                                   "'; only PolyData (.vtp) is supported");
    }
    const std::string* order = root.attribute("byte_order");
    big_endian_ = order != nullptr && *order == "BigEndian";
    const std::string* header = root.attribute("header_type");
    if (header != nullptr) {
      if (*header == "UInt64") header_size_ = 8;
      else if (*header != "UInt32") doc_.failAt(root.offset, "unsupported header_type '" + *header + "' (expected UInt32 or UInt64)");
    }
    const std::string* compressor = root.attribute("compressor");
    if (compressor != nullptr && !compressor->empty()) {
      if (*compressor != "vtkZLibDataCompressor") {
        unsupported_compressor_ = *compressor;
      } else {
        compressed_ = true;
      }
    }
    const auto appended = doc_.children(doc_.root(), "AppendedData");
    if (!appended.empty()) {
      const XmlElement& a = doc_.element(appended.front());
      const std::string* encoding = a.attribute("encoding");
      appended_base64_ = encoding != nullptr && *encoding == "base64";
      if (encoding != nullptr && !appended_base64_ && *encoding != "raw") {
        doc_.failAt(a.offset, "unsupported AppendedData encoding '" + *encoding + "' (expected raw or base64)");
      }
      const std::size_t underscore = text_.find('_', a.content_begin);
      if (underscore == std::string::npos || underscore >= a.content_end) {
        doc_.failAt(a.offset, "AppendedData does not start with '_'");
      }
      appended_begin_ = underscore + 1;
      appended_end_ = a.content_end;
      have_appended_ = true;
    }

    const auto polydata = doc_.children(doc_.root(), "PolyData");
    if (polydata.empty()) doc_.failAt(root.offset, "no <PolyData> element");
    PolyData result;
    for (std::size_t piece : doc_.children(polydata.front(), "Piece")) readPiece(piece, result);
    if (result.pointCount() == 0) doc_.failAt(doc_.element(polydata.front()).offset, "no points (no <Piece> with <Points>)");
    return result;
  }

 private:
  long long countAttribute(const XmlElement& e, const char* key) {
    const std::string* value = e.attribute(key);
    if (value == nullptr) return 0;
    long long n;
    if (!parseInt(*value, n) || n < 0) doc_.failAt(e.offset, std::string(key) + "=\"" + *value + "\" is not a non-negative integer");
    // Bounded by the file size so that a corrupt count cannot overflow or trigger a huge allocation.
    if (static_cast<unsigned long long>(n) > text_.size()) {
      doc_.failAt(e.offset, std::string(key) + "=\"" + *value + "\" is more than a file of " + std::to_string(text_.size()) +
                                " bytes can hold (corrupt file?)");
    }
    return n;
  }

  void readPiece(std::size_t piece_index, PolyData& result) {
    const XmlElement& piece = doc_.element(piece_index);
    const long long points = countAttribute(piece, "NumberOfPoints");
    PolyData local;
    const auto point_nodes = doc_.children(piece_index, "Points");
    if (points > 0) {
      if (point_nodes.empty()) doc_.failAt(piece.offset, "<Piece> declares " + std::to_string(points) + " points but has no <Points>");
      const auto arrays = doc_.children(point_nodes.front(), "DataArray");
      if (arrays.empty()) doc_.failAt(doc_.element(point_nodes.front()).offset, "<Points> has no <DataArray>");
      const XmlElement& array = doc_.element(arrays.front());
      const long long components = array.attribute("NumberOfComponents") ? countAttribute(array, "NumberOfComponents") : 1;
      if (components != 3) {
        doc_.failAt(array.offset, "the Points DataArray must have NumberOfComponents=\"3\", found " + std::to_string(components));
      }
      local.xyz = readArray(array, static_cast<std::size_t>(3 * points), "Points", true);
    }
    readCellsInto(piece_index, "Polys", countAttribute(piece, "NumberOfPolys"), local.polys, points);
    readCellsInto(piece_index, "Strips", countAttribute(piece, "NumberOfStrips"), local.strips, points);
    readCellsInto(piece_index, "Lines", countAttribute(piece, "NumberOfLines"), local.lines, points);

    const auto shift = static_cast<std::int64_t>(result.pointCount());
    result.xyz.insert(result.xyz.end(), local.xyz.begin(), local.xyz.end());
    result.polys.append(local.polys, shift);
    result.strips.append(local.strips, shift);
    result.lines.append(local.lines, shift);
  }

  void readCellsInto(std::size_t piece_index, const char* section, long long cells, CellList& out, long long points) {
    if (cells == 0) return;
    const auto nodes = doc_.children(piece_index, section);
    const XmlElement& piece = doc_.element(piece_index);
    if (nodes.empty()) {
      doc_.failAt(piece.offset, "<Piece> declares " + std::to_string(cells) + " " + section + " cells but has no <" + section + ">");
    }
    const XmlElement* connectivity = nullptr;
    const XmlElement* offsets = nullptr;
    for (std::size_t a : doc_.children(nodes.front(), "DataArray")) {
      const std::string* name = doc_.element(a).attribute("Name");
      if (name != nullptr && *name == "connectivity") connectivity = &doc_.element(a);
      if (name != nullptr && *name == "offsets") offsets = &doc_.element(a);
    }
    const XmlElement& node = doc_.element(nodes.front());
    if (connectivity == nullptr || offsets == nullptr) {
      doc_.failAt(node.offset, std::string("<") + section + "> needs DataArrays named \"connectivity\" and \"offsets\"");
    }
    const std::vector<double> ends = readArray(*offsets, static_cast<std::size_t>(cells), std::string(section) + " offsets", false);
    const auto total = static_cast<long long>(ends.back());
    std::int64_t previous = 0;
    for (double end : ends) {
      const auto e = static_cast<std::int64_t>(end);
      if (e < previous) doc_.failAt(offsets->offset, std::string(section) + " offsets must not decrease");
      out.offsets.push_back(e);
      previous = e;
    }
    const std::vector<double> conn = readArray(*connectivity, static_cast<std::size_t>(total), std::string(section) + " connectivity", false);
    for (std::size_t i = 0; i < conn.size(); ++i) {
      const auto v = static_cast<std::int64_t>(conn[i]);
      if (v < 0 || v >= points) {
        doc_.failAt(connectivity->offset, std::string(section) + " connectivity entry " + std::to_string(i) + " refers to point " +
                                              std::to_string(v) + " but the piece has only " + std::to_string(points) +
                                              " points (valid: 0 to " + std::to_string(points - 1) + ")");
      }
      out.connectivity.push_back(v);
    }
  }

  // Values of a DataArray as doubles (exact for any index below 2^53), checking the count.
  std::vector<double> readArray(const XmlElement& array, std::size_t expected, const std::string& what, bool coordinates) {
    const std::string* format = array.attribute("format");
    const std::string* type_name = array.attribute("type");
    if (type_name == nullptr) doc_.failAt(array.offset, what + " DataArray has no type attribute");
    VtkType type;
    if (!xmlType(*type_name, type)) doc_.failAt(array.offset, "unsupported DataArray type '" + *type_name + "' in " + what);
    if (!coordinates && type.floating) doc_.failAt(array.offset, what + " must be an integer DataArray, found type " + *type_name);
    std::vector<double> values;
    values.reserve(std::min(expected, text_.size()));  // a corrupt count must not cause a huge allocation

    if (format == nullptr || *format == "ascii") {
      TextScanner sc(doc_.content(array), 0, doc_.lineAt(array.content_begin));
      std::string_view tok;
      while (sc.next(tok)) {
        double value;
        if (!parseDouble(tok, value)) failAtLine(path_, sc.tokenLine(), "expected a number in " + what + ", found " + quoted(tok));
        if (!std::isfinite(value)) failAtLine(path_, sc.tokenLine(), "value " + quoted(tok) + " in " + what + " is not finite");
        if (!type.floating && value != std::floor(value)) {
          failAtLine(path_, sc.tokenLine(), "expected an integer in " + what + ", found " + quoted(tok));
        }
        values.push_back(value);
      }
    } else if (*format == "binary") {
      std::string raw;
      if (!decodeBase64(doc_.content(array), raw)) doc_.failAt(array.offset, what + " DataArray is not valid base64");
      const std::string payload = unpackBlock(raw, 0, array, what);
      decodeValues(payload, type, array, what, values);
    } else if (*format == "appended") {
      if (!have_appended_) doc_.failAt(array.offset, what + " DataArray is format=\"appended\" but the file has no <AppendedData>");
      long long offset;
      const std::string* offset_text = array.attribute("offset");
      if (offset_text == nullptr || !parseInt(*offset_text, offset) || offset < 0) {
        doc_.failAt(array.offset, what + " DataArray is format=\"appended\" but has no valid offset attribute");
      }
      const std::string payload = appendedBlock(static_cast<std::size_t>(offset), array, what);
      decodeValues(payload, type, array, what, values);
    } else {
      doc_.failAt(array.offset, "unknown DataArray format '" + *format + "' in " + what + " (expected ascii, binary or appended)");
    }

    if (values.size() != expected) {
      doc_.failAt(array.offset, what + " DataArray holds " + std::to_string(values.size()) + " values, expected " +
                                    std::to_string(expected) + (coordinates ? " (3 per point)" : ""));
    }
    if (!coordinates) {
      for (double v : values) {
        // Beyond 2^53 doubles stop being exact integers; no real index or offset comes near it.
        if (!(std::abs(v) < 9.0e15)) doc_.failAt(array.offset, what + " holds an out-of-range integer " + std::to_string(v));
      }
    }
    if (coordinates) {
      for (std::size_t i = 0; i < values.size(); ++i) {
        if (!std::isfinite(values[i])) doc_.failAt(array.offset, "point " + std::to_string(i / 3) + " has a NaN or infinite coordinate");
      }
    }
    return values;
  }

  static bool xmlType(const std::string& name, VtkType& type) {
    static const std::pair<const char*, VtkType> table[] = {
        {"Float32", {4, true, true}}, {"Float64", {8, true, true}}, {"Int8", {1, false, true}},
        {"UInt8", {1, false, false}}, {"Int16", {2, false, true}}, {"UInt16", {2, false, false}},
        {"Int32", {4, false, true}},  {"UInt32", {4, false, false}}, {"Int64", {8, false, true}},
        {"UInt64", {8, false, false}}};
    for (const auto& entry : table) {
      if (name == entry.first) {
        type = entry.second;
        return true;
      }
    }
    return false;
  }

  std::uint64_t headerValue(const std::string& bytes, std::size_t index) const {
    const char* p = bytes.data() + index * header_size_;
    return header_size_ == 8 ? readBinary<std::uint64_t>(p, big_endian_) : readBinary<std::uint32_t>(p, big_endian_);
  }

  void requireZlib(const XmlElement& array, const std::string& what) const {
    if (!unsupported_compressor_.empty()) {
      doc_.failAt(array.offset, what + " is compressed with " + unsupported_compressor_ +
                                    ", which is not supported (only vtkZLibDataCompressor); re-save without compression");
    }
  }

  // One binary block (header + data) starting at `at` in `raw`, returned uncompressed.
  std::string unpackBlock(const std::string& raw, std::size_t at, const XmlElement& array, const std::string& what) const {
    requireZlib(array, what);
    const std::string truncated = what + " binary data is shorter than its header says (truncated file?)";
    if (!compressed_) {
      if (raw.size() < at + header_size_) doc_.failAt(array.offset, truncated);
      const std::uint64_t bytes = headerValue(raw.substr(at, header_size_), 0);
      if (raw.size() - at - header_size_ < bytes) doc_.failAt(array.offset, truncated);
      return raw.substr(at + header_size_, static_cast<std::size_t>(bytes));
    }
    if (raw.size() < at + 3 * header_size_) doc_.failAt(array.offset, truncated);
    const std::string head = raw.substr(at, 3 * header_size_);
    const std::uint64_t blocks = headerValue(head, 0);
    const std::uint64_t block_size = headerValue(head, 1);
    const std::uint64_t last_size = headerValue(head, 2);
    if (blocks > raw.size()) doc_.failAt(array.offset, truncated);
    const std::size_t header_bytes = static_cast<std::size_t>(3 + blocks) * header_size_;
    if (raw.size() < at + header_bytes) doc_.failAt(array.offset, truncated);
    const std::string header = raw.substr(at, header_bytes);
    std::size_t cursor = at + header_bytes;
    std::string out;
    for (std::uint64_t b = 0; b < blocks; ++b) {
      const std::uint64_t packed = headerValue(header, 3 + static_cast<std::size_t>(b));
      const std::uint64_t unpacked = (b + 1 == blocks && last_size != 0) ? last_size : block_size;
      if (raw.size() - cursor < packed) doc_.failAt(array.offset, truncated);
      // zlib cannot expand more than about 1032:1, so a larger claim means a corrupt header, not a big array.
      if (unpacked > packed * 1032 + 64) {
        doc_.failAt(array.offset, what + " compressed block " + std::to_string(b) + " has an impossible size in its header");
      }
      std::string buffer(static_cast<std::size_t>(unpacked), '\0');
      uLongf produced = static_cast<uLongf>(unpacked);
      const int status = uncompress(reinterpret_cast<Bytef*>(&buffer[0]), &produced,
                                    reinterpret_cast<const Bytef*>(raw.data() + cursor), static_cast<uLong>(packed));
      if (status != Z_OK || produced != unpacked) {
        doc_.failAt(array.offset, what + " compressed block " + std::to_string(b) + " is corrupt (zlib error " +
                                      std::to_string(status) + ")");
      }
      out += buffer;
      cursor += static_cast<std::size_t>(packed);
    }
    return out;
  }

  // Appended data: raw bytes at a byte offset, or base64 where header and data are encoded separately.
  std::string appendedBlock(std::size_t offset, const XmlElement& array, const std::string& what) const {
    const std::string_view section = std::string_view(text_).substr(appended_begin_, appended_end_ - appended_begin_);
    if (offset >= section.size()) doc_.failAt(array.offset, what + " appended offset " + std::to_string(offset) + " lies beyond the data");
    if (!appended_base64_) return unpackBlock(std::string(section.substr(offset)), 0, array, what);

    requireZlib(array, what);
    const std::string bad = what + " appended base64 data is invalid or truncated";
    auto decode = [&](std::size_t from, std::size_t bytes, std::string& out) {
      const std::size_t chars = (bytes + 2) / 3 * 4;
      if (from + chars > section.size() || !decodeBase64(section.substr(from, chars), out)) doc_.failAt(array.offset, bad);
      return from + chars;
    };
    std::string header;
    if (!compressed_) {
      std::size_t cursor = decode(offset, header_size_, header);
      const std::uint64_t bytes = headerValue(header, 0);
      if (bytes > section.size()) doc_.failAt(array.offset, bad);
      std::string data;
      decode(cursor, static_cast<std::size_t>(bytes), data);
      data.resize(std::min<std::size_t>(data.size(), static_cast<std::size_t>(bytes)));
      return data;
    }
    decode(offset, 3 * header_size_, header);
    const std::uint64_t blocks = headerValue(header, 0);
    if (blocks > section.size()) doc_.failAt(array.offset, bad);
    header.clear();
    std::size_t cursor = decode(offset, static_cast<std::size_t>(3 + blocks) * header_size_, header);
    std::uint64_t packed_total = 0;
    for (std::uint64_t b = 0; b < blocks; ++b) {
      packed_total += headerValue(header, 3 + static_cast<std::size_t>(b));
      if (packed_total > section.size()) doc_.failAt(array.offset, bad);
    }
    std::string data;
    decode(cursor, static_cast<std::size_t>(packed_total), data);
    return unpackBlock(header.substr(0, static_cast<std::size_t>(3 + blocks) * header_size_) + data, 0, array, what);
  }

  void decodeValues(const std::string& payload, const VtkType& type, const XmlElement& array, const std::string& what,
                    std::vector<double>& values) const {
    if (payload.size() % type.size != 0) {
      doc_.failAt(array.offset, what + " binary data has " + std::to_string(payload.size()) +
                                    " bytes, not a whole number of values");
    }
    for (std::size_t i = 0; i < payload.size(); i += type.size) {
      values.push_back(decodeBinaryNumber(payload.data() + i, type, big_endian_));
    }
  }

  const std::string& path_;
  const std::string& text_;
  XmlDocument doc_;
  bool big_endian_ = false;
  std::size_t header_size_ = 4;
  bool compressed_ = false;
  std::string unsupported_compressor_;
  bool have_appended_ = false;
  bool appended_base64_ = false;
  std::size_t appended_begin_ = 0;
  std::size_t appended_end_ = 0;
};

PolyData readVtp(const std::string& path) {
  const std::string text = readWholeFile(path);
  if (text.empty()) fail(path, "file is empty");
  return VtpReader(path, text).read();
}

// ---------------------------------------------------------------------------------------------------------------
// Wavefront OBJ

PolyData readObj(const std::string& path) {
  const std::string text = readWholeFile(path);
  if (text.empty()) fail(path, "file is empty");
  PolyData data;
  // Positive indices may in principle refer to vertices defined later, so they are checked at the end.
  std::vector<std::pair<long, long long>> deferred;  // (line, 1-based index)
  long line_number = 0;
  std::size_t pos = 0;
  std::string logical;

  auto resolve = [&](std::string_view ref, long line, const char* record) -> std::int64_t {
    const std::string_view index_text = ref.substr(0, ref.find('/'));
    long long index;
    if (!parseInt(index_text, index)) {
      failAtLine(path, line, std::string("expected a vertex index in '") + record + "' record, found " + quoted(ref));
    }
    if (index == 0) failAtLine(path, line, std::string("vertex index 0 in '") + record + "' record; OBJ indices start at 1");
    const auto defined = static_cast<long long>(data.pointCount());
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

    TextScanner sc(logical, 0, first_line);
    std::string_view keyword;
    if (!sc.next(keyword)) continue;
    if (keyword == "v") {
      double c[3];
      std::string_view tok;
      for (int k = 0; k < 3; ++k) {
        if (!sc.next(tok)) {
          failAtLine(path, first_line, "expected 3 coordinates per vertex ('v x y z'), found " + std::to_string(k));
        }
        if (!parseDouble(tok, c[k])) failAtLine(path, first_line, "vertex coordinate " + quoted(tok) + " is not a number");
        if (!std::isfinite(c[k])) failAtLine(path, first_line, "vertex coordinate " + quoted(tok) + " is not finite");
      }
      // Optional w or colour values may follow; they must still be numbers.
      while (sc.next(tok)) {
        double ignored;
        if (!parseDouble(tok, ignored)) failAtLine(path, first_line, "unexpected " + quoted(tok) + " after the vertex coordinates");
      }
      data.xyz.insert(data.xyz.end(), c, c + 3);
    } else if (keyword == "f" || keyword == "l") {
      const bool face = keyword == "f";
      CellList& cells = face ? data.polys : data.lines;
      std::string_view tok;
      std::size_t count = 0;
      while (sc.next(tok)) {
        cells.connectivity.push_back(resolve(tok, first_line, face ? "f" : "l"));
        ++count;
      }
      if (face && count < 3) failAtLine(path, first_line, "face has " + std::to_string(count) + " vertices; at least 3 are needed");
      if (!face && count < 2) failAtLine(path, first_line, "line has " + std::to_string(count) + " vertices; at least 2 are needed");
      cells.offsets.push_back(static_cast<std::int64_t>(cells.connectivity.size()));
    }
    // Everything else (vt, vn, g, o, s, usemtl, mtllib, ...) carries nothing we need.
  }
  for (const auto& entry : deferred) {
    if (entry.second > static_cast<long long>(data.pointCount())) {
      failAtLine(path, entry.first, "vertex index " + std::to_string(entry.second) + " is out of range: the file defines only " +
                                        std::to_string(data.pointCount()) + " vertices");
    }
  }
  return data;
}

// ---------------------------------------------------------------------------------------------------------------

PolyData readPolyData(const std::string& path, const std::string& ext) {
  if (ext == ".vtk") return readLegacyVtk(path);
  if (ext == ".vtp") return readVtp(path);
  return readObj(path);
}

[[noreturn]] void unknownExtension(const std::string& path, const std::string& ext, const char* supported) {
  fail(path, (ext.empty() ? std::string("has no file extension") : "unknown file extension '" + ext + "'") +
                 "; supported: " + supported);
}

}  // namespace

TriangleMesh loadTriangleMesh(const std::string& path, double scale_to_metres) {
  checkScale(path, scale_to_metres);
  const std::string ext = lowerExtension(path);
  if (ext == ".stl") return readStl(path, scale_to_metres);
  if (ext == ".vtk" || ext == ".vtp" || ext == ".obj") {
    return trianglesFromPolyData(path, readPolyData(path, ext), scale_to_metres);
  }
  unknownExtension(path, ext, ".stl, .vtk, .vtp, .obj");
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
    return polylinesFromPolyData(path, readPolyData(path, ext), scale_to_metres);
  }
  if (ext == ".stl") fail(path, "STL files hold triangles, not polylines; fibres must be .vtk, .vtp or .obj");
  unknownExtension(path, ext, ".vtk, .vtp, .obj");
}

// Writers throw std::runtime_error naming the file: they are not loaders.
void savePolylinesVtk(const std::string& path, const std::vector<Polyline>& lines) {
  std::size_t points = 0;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    if (lines[i].cols() < 2) {
      throw std::runtime_error(path + ": cannot save polyline " + std::to_string(i) + " with fewer than 2 points");
    }
    if (!lines[i].allFinite()) throw std::runtime_error(path + ": polyline " + std::to_string(i) + " has non-finite points");
    points += static_cast<std::size_t>(lines[i].cols());
  }
  std::ofstream out(path);
  if (!out) throw std::runtime_error(path + ": cannot open for writing: " + std::strerror(errno));
  out << "# vtk DataFile Version 3.0\nmuscle_deformation polylines (metres)\nASCII\nDATASET POLYDATA\n";
  out << "POINTS " << points << " double\n" << std::setprecision(std::numeric_limits<double>::max_digits10);
  for (const auto& line : lines) {
    for (Eigen::Index i = 0; i < line.cols(); ++i) out << line(0, i) << ' ' << line(1, i) << ' ' << line(2, i) << '\n';
  }
  out << "LINES " << lines.size() << ' ' << (points + lines.size()) << '\n';
  std::size_t next = 0;
  for (const auto& line : lines) {
    out << line.cols();
    for (Eigen::Index i = 0; i < line.cols(); ++i) out << ' ' << next++;
    out << '\n';
  }
  out.close();
  if (!out) throw std::runtime_error(path + ": write failed");
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
  std::ofstream out(path, std::ios::binary);
  if (!out) throw std::runtime_error(path + ": cannot open for writing: " + std::strerror(errno));
  // The header must not start with "solid", or naive readers take the file for ASCII.
  char header[80] = {};
  std::snprintf(header, sizeof header, "binary STL written by muscle_deformation");
  out.write(header, sizeof header);
  auto put32 = [&out](std::uint32_t v) {
    const char bytes[4] = {static_cast<char>(v & 0xff), static_cast<char>((v >> 8) & 0xff),
                           static_cast<char>((v >> 16) & 0xff), static_cast<char>((v >> 24) & 0xff)};
    out.write(bytes, 4);
  };
  auto putFloat = [&put32](double value) {
    const float f = static_cast<float>(value);
    std::uint32_t bits;
    std::memcpy(&bits, &f, 4);
    put32(bits);
  };
  put32(static_cast<std::uint32_t>(mesh.triangleCount()));
  for (Eigen::Index t = 0; t < mesh.triangleCount(); ++t) {
    const Eigen::Vector3d a = mesh.vertices.col(mesh.triangles(0, t));
    const Eigen::Vector3d b = mesh.vertices.col(mesh.triangles(1, t));
    const Eigen::Vector3d c = mesh.vertices.col(mesh.triangles(2, t));
    Eigen::Vector3d normal = (b - a).cross(c - a);
    if (normal.norm() > 0.0) normal.normalize();
    for (int k = 0; k < 3; ++k) putFloat(normal[k]);
    for (const Eigen::Vector3d* v : {&a, &b, &c}) {
      for (int k = 0; k < 3; ++k) putFloat((*v)[k]);
    }
    out.write("\0\0", 2);  // attribute byte count
  }
  out.close();
  if (!out) throw std::runtime_error(path + ": write failed");
}

}  // namespace muscle_deformation
