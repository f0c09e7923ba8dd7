// Sample a sticky three-state Gaussian HMM with voicepuppet::core, decode it with Viterbi and
// report how many frames the decoder got right. Exits non-zero if decoding is poor, so CI can
// run it as a check that the installed library links and works.
#include <voicepuppet/hmm.hpp>
#include <voicepuppet/hmm_gaussian.hpp>

#include <iostream>

int main() {
  using namespace voicepuppet;
  const Index n = 3, d = 2;
  VectorXd start = VectorXd::Constant(n, 1.0 / n);
  RowMatrixXd trans(n, n);
  trans << 0.90, 0.05, 0.05,  //
      0.05, 0.90, 0.05,       //
      0.05, 0.05, 0.90;
  RowMatrixXd means(n, d);
  means << 0, 0, 4, 0, 0, 4;
  RowMatrixXd covars(n * d, d);  // [N, D, D] stacked
  for (Index i = 0; i < n; ++i) covars.middleRows(i * d, d) = RowMatrixXd::Identity(d, d);

  const SampleResult sample = gaussian_hmm_sample(start, trans, means, covars, CovarianceType::Full, 1000, 42);
  const RowMatrixXd log_b = gaussian_log_density(sample.X, means, covars, CovarianceType::Full);
  const ViterbiResult best = viterbi(log_b, start, trans, VectorXi());
  const double ll = log_likelihood(log_b, start, trans, VectorXi());

  Index correct = 0;
  for (Index t = 0; t < sample.states.size(); ++t) correct += best.path[t] == sample.states[t];
  const BuildInfo info = build_info();
  std::cout << "voicepuppet " << info.version << " (" << info.compiler << ", " << info.build_type << ")\n"
            << "log p(X) = " << ll << ", Viterbi log p = " << best.log_probability << "\n"
            << "Viterbi recovered " << correct << " of " << sample.states.size() << " states\n";
  return correct > 950 ? 0 : 1;
}
