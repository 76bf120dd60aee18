// Finite-difference gradient check in double precision for the sparse ops.
#pragma once

#include <gtest/gtest.h>
#include <torch/autograd.h>
#include <torch/types.h>

#include <functional>
#include <vector>

namespace dss::test {

// Compares autograd's gradient of L = sum(f(inputs) * R), R fixed random, with
// central differences for every element of every input that requires grad.
inline void expectGradientsMatch(const std::function<torch::Tensor(const std::vector<torch::Tensor>&)>& f,
                                 std::vector<torch::Tensor> inputs, double eps = 1e-6, double tolerance = 1e-7) {
  for (auto& t : inputs) t = t.detach().to(torch::kDouble).requires_grad_(true);
  torch::Tensor out = f(inputs);
  ASSERT_EQ(out.scalar_type(), torch::kDouble);
  torch::manual_seed(99);
  const torch::Tensor r = torch::randn_like(out);
  (out * r).sum().backward();
  for (std::size_t k = 0; k < inputs.size(); ++k) {
    const torch::Tensor analytic = inputs[k].grad();
    ASSERT_TRUE(analytic.defined()) << "input " << k << " got no gradient";
    torch::Tensor values = inputs[k].detach().clone();
    auto flat = values.view({-1});
    for (std::int64_t i = 0; i < flat.numel(); ++i) {
      const double saved = flat[i].item<double>();
      auto eval = [&](double v) {
        flat[i] = v;
        std::vector<torch::Tensor> args = inputs;
        args[k] = values;
        torch::NoGradGuard no_grad;
        return (f(args) * r).sum().item<double>();
      };
      const double numeric = (eval(saved + eps) - eval(saved - eps)) / (2 * eps);
      flat[i] = saved;
      const double a = analytic.view({-1})[i].item<double>();
      ASSERT_NEAR(a, numeric, tolerance * std::max(1.0, std::abs(numeric))) << "input " << k << " element " << i;
    }
  }
}

}  // namespace dss::test
