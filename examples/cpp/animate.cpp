// Animate a voice puppet from audio feature frames, without Python: the C++ side of a game
// engine or a plug-in that computes its features itself (or reads them from `voicepuppet
// features AUDIO --puppet PUPPET.vpp -o F.csv`).
//
//   voicepuppet_animate PUPPET.vpp FEATURES.csv OUT.csv [--fps F] [--posterior]
//
// FEATURES.csv: one row per frame at the puppet's rate, the puppet's feature columns (a header
// line and leading frame/time columns are skipped if present: only the last A columns are used).
// OUT.csv: frame,time,x0,y0,x1,y1,... landmarks in pixels.
#include <voicepuppet/puppet.hpp>

#include <cstdio>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

namespace {

voicepuppet::RowMatrixXd read_csv(const std::string& path, voicepuppet::Index cols) {
  std::ifstream in(path);
  if (!in) throw std::invalid_argument("cannot open features file '" + path + "'");
  std::vector<std::vector<double>> rows;
  std::string line;
  for (int lineno = 1; std::getline(in, line); ++lineno) {
    if (line.empty()) continue;
    std::vector<double> row;
    std::stringstream ss(line);
    std::string cell;
    bool numeric = true;
    while (std::getline(ss, cell, ',')) {
      try {
        size_t used = 0;
        row.push_back(std::stod(cell, &used));
      } catch (const std::exception&) {
        numeric = false;
        break;
      }
    }
    if (!numeric) {
      if (rows.empty()) continue;  // a header line
      throw std::invalid_argument(path + ":" + std::to_string(lineno) + ": not a number");
    }
    if (static_cast<voicepuppet::Index>(row.size()) < cols) {
      throw std::invalid_argument(path + ":" + std::to_string(lineno) + ": " + std::to_string(row.size()) +
                                  " columns, the puppet needs " + std::to_string(cols));
    }
    rows.emplace_back(row.end() - cols, row.end());
  }
  if (rows.empty()) throw std::invalid_argument("features file '" + path + "' has no frames");
  voicepuppet::RowMatrixXd m(static_cast<voicepuppet::Index>(rows.size()), cols);
  for (size_t t = 0; t < rows.size(); ++t) {
    for (voicepuppet::Index j = 0; j < cols; ++j) m(static_cast<voicepuppet::Index>(t), j) = rows[t][j];
  }
  return m;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace voicepuppet;
  if (argc < 4) {
    std::cerr << "usage: voicepuppet_animate PUPPET.vpp FEATURES.csv OUT.csv [--fps F] [--posterior]\n";
    return 2;
  }
  try {
    AnimateOptions options;
    for (int i = 4; i < argc; ++i) {
      const std::string a = argv[i];
      if (a == "--posterior") {
        options.posterior = true;
      } else if (a == "--fps" && i + 1 < argc) {
        options.fps = std::stod(argv[++i]);
      } else {
        throw std::invalid_argument("unknown option '" + a + "'");
      }
    }
    const Puppet puppet = Puppet::load(argv[1]);
    const RowMatrixXd features = read_csv(argv[2], puppet.n_features());
    const AnimateResult r = puppet.animate(features, options);
    const double fps = options.fps > 0 ? options.fps : puppet.fps();
    const std::string out = argv[3], tmp = out + ".tmp";
    {
      std::ofstream os(tmp);
      if (!os) throw std::runtime_error("cannot write '" + out + "'");
      os.precision(17);
      os << "frame,time";
      for (Index q = 0; q < puppet.n_points(); ++q) os << ",x" << q << ",y" << q;
      os << "\n";
      for (Index t = 0; t < r.points.rows(); ++t) {
        os << t << "," << t / fps;
        for (Index j = 0; j < r.points.cols(); ++j) os << "," << r.points(t, j);
        os << "\n";
      }
      if (!os.flush()) throw std::runtime_error("writing '" + out + "' failed");
    }
    if (std::rename(tmp.c_str(), out.c_str()) != 0) throw std::runtime_error("cannot move '" + tmp + "' to '" + out + "'");
    std::cout << "animated " << features.rows() << " feature frames into " << r.points.rows() << " frames of "
              << puppet.n_points() << " points (log p = " << r.log_likelihood << "); wrote " << out << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "voicepuppet_animate: error: " << e.what() << "\n";
    return 2;
  }
}
