// Sparse engine: rulebooks, gradient checks of every op, sparse = dense at the
// active sites, edge cases.
#include <torch/nn/functional/conv.h>
#include <torch/nn/functional/pooling.h>

#include <set>

#include "digital_sun_sensor/common/random.h"
#include "digital_sun_sensor/sparse/ops.h"
#include "gradcheck.h"

namespace dss::sparse {
using dss::test::expectGradientsMatch;
namespace {

namespace F = torch::nn::functional;

// `count` distinct random sites per image, always including the four corners.
std::shared_ptr<const SiteSet> randomSites(int batch, int height, int width, int count, std::uint64_t seed) {
  Rng rng(seed);
  std::vector<Site> sites;
  for (int b = 0; b < batch; ++b) {
    std::set<std::pair<int, int>> taken{{0, 0}, {0, width - 1}, {height - 1, 0}, {height - 1, width - 1}};
    while (static_cast<int>(taken.size()) < count)
      taken.insert({static_cast<int>(rng.uniform() * height), static_cast<int>(rng.uniform() * width)});
    for (const auto& [y, x] : taken) sites.push_back({b, y, x});
  }
  return std::make_shared<SiteSet>(batch, height, width, std::move(sites));
}

torch::Tensor denseWeight(const torch::Tensor& w, int k) {
  return w.permute({2, 1, 0}).reshape({w.size(2), w.size(1), k, k});
}

// Dense map values at the sites, as [sites, C].
torch::Tensor atSites(const torch::Tensor& dense, const SiteSet& sites) {
  auto out = torch::empty({sites.size(), dense.size(1)}, dense.options());
  for (int i = 0; i < sites.size(); ++i) {
    const Site& s = sites.site(i);
    out[i] = dense.index({s.batch, torch::indexing::Slice(), s.y, s.x});
  }
  return out;
}

TEST(SiteSet, RejectsDuplicatesAndOutOfRange) {
  try {
    SiteSet({1, 4, 4, {{0, 1, 2}, {0, 1, 2}}});
    FAIL() << "duplicate accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("duplicate site (batch 0, y 1, x 2)"), std::string::npos) << e.what();
  }
  EXPECT_THROW(SiteSet(1, 4, 4, {{0, 4, 0}}), std::invalid_argument);
  EXPECT_THROW(SiteSet(1, 4, 4, {{1, 0, 0}}), std::invalid_argument);
  const SiteSet s(2, 4, 4, {{1, 3, 3}, {0, 0, 0}});
  EXPECT_EQ(s.find(1, 3, 3), 0);
  EXPECT_EQ(s.find(0, 0, 0), 1);
  EXPECT_EQ(s.find(0, 3, 3), -1);
  EXPECT_EQ(s.find(0, -1, 0), -1);
}

TEST(Rulebook, EmptyImage) {
  auto sites = std::make_shared<SiteSet>(1, 16, 16, std::vector<Site>{});
  auto subm = submanifoldRulebook(sites, 3);
  EXPECT_EQ(subm->numPairs(), 0);
  auto strided = stridedRulebook(sites, 3, 2, 1);
  EXPECT_EQ(strided->output->size(), 0);
  auto y = sparseConv(torch::zeros({0, 2}), torch::randn({9, 2, 5}), *subm);
  EXPECT_EQ(y.size(0), 0);
  EXPECT_EQ(y.size(1), 5);
  auto pooled = globalMaxPool(torch::zeros({0, 2}), *sites);
  EXPECT_EQ(pooled.abs().sum().item<float>(), 0.0f);
  EXPECT_EQ(globalAvgPool(torch::zeros({0, 2}), *sites).abs().sum().item<float>(), 0.0f);
}

TEST(Rulebook, OneActivePixel) {
  auto sites = std::make_shared<SiteSet>(1, 9, 9, std::vector<Site>{{0, 3, 4}});
  auto subm = submanifoldRulebook(sites, 3);
  EXPECT_EQ(subm->numPairs(), 1);  // only the centre offset: (0, 0)
  EXPECT_EQ(subm->offset_begin[5] - subm->offset_begin[4], 1);
  // k3 s2 p1: rows o with 2o-1 <= 3 <= 2o+1 -> o in {1, 2}; columns 2o-1 <= 4 <= 2o+1 -> o = 2.
  auto strided = stridedRulebook(sites, 3, 2, 1);
  ASSERT_EQ(strided->output->size(), 2);
  EXPECT_GE(strided->output->find(0, 1, 2), 0);
  EXPECT_GE(strided->output->find(0, 2, 2), 0);
  EXPECT_EQ(strided->output->height(), 5);
}

TEST(Rulebook, RejectsBadGeometry) {
  auto sites = std::make_shared<SiteSet>(1, 4, 4, std::vector<Site>{{0, 0, 0}});
  EXPECT_THROW(submanifoldRulebook(sites, 2), std::invalid_argument);
  EXPECT_THROW(stridedRulebook(sites, 3, 0, 1), std::invalid_argument);
  EXPECT_THROW(stridedRulebook(sites, 9, 2, 0), std::invalid_argument);
  auto rb = submanifoldRulebook(sites, 3);
  EXPECT_THROW(sparseConv(torch::zeros({2, 3}), torch::zeros({9, 3, 1}), *rb), std::invalid_argument);
  EXPECT_THROW(sparseConv(torch::zeros({1, 3}), torch::zeros({9, 2, 1}), *rb), std::invalid_argument);
}

TEST(SparseVsDense, SubmanifoldConvEqualsDenseAtActiveSites) {
  torch::manual_seed(1);
  // 3 input channels: one im2col GEMM; 40: a GEMM per kernel offset.
  for (int c_in : {3, 40})
    for (int k : {1, 3, 5}) {
      auto sites = randomSites(2, 11, 13, 40, 7);
      auto rb = submanifoldRulebook(sites, k);
      auto x = torch::randn({sites->size(), c_in}, torch::kDouble);
      auto w = torch::randn({k * k, c_in, 4}, torch::kDouble);
      auto sparse_out = sparseConv(x, w, *rb);
      auto dense_out = F::conv2d(toDense(x, *sites), denseWeight(w, k), F::Conv2dFuncOptions().padding(k / 2));
      EXPECT_LT((sparse_out - atSites(dense_out, *sites)).abs().max().item<double>(), 1e-12) << "k=" << k;
    }
}

TEST(SparseVsDense, StridedConvEqualsDenseOnItsSites) {
  torch::manual_seed(2);
  struct Geometry {
    int k, s, p;
  };
  for (int c_in : {2, 40})
    for (const Geometry g : {Geometry{3, 2, 1}, Geometry{7, 2, 3}, Geometry{2, 2, 0}, Geometry{1, 2, 0}}) {
      auto sites = randomSites(2, 16, 15, 30, 11);
      auto rb = stridedRulebook(sites, g.k, g.s, g.p);
      auto x = torch::randn({sites->size(), c_in}, torch::kDouble);
      auto w = torch::randn({g.k * g.k, c_in, 3}, torch::kDouble);
      auto sparse_out = sparseConv(x, w, *rb);
      auto dense_out =
          F::conv2d(toDense(x, *sites), denseWeight(w, g.k), F::Conv2dFuncOptions().stride(g.s).padding(g.p));
      ASSERT_EQ(dense_out.size(2), rb->output->height());
      ASSERT_EQ(dense_out.size(3), rb->output->width());
      EXPECT_LT((sparse_out - atSites(dense_out, *rb->output)).abs().max().item<double>(), 1e-12) << "k=" << g.k;
      // Its sites are exactly those whose receptive field holds an active input.
      auto reach =
          F::conv2d(toDense(torch::ones({sites->size(), 1}, torch::kDouble), *sites),
                    torch::ones({1, 1, g.k, g.k}, torch::kDouble), F::Conv2dFuncOptions().stride(g.s).padding(g.p));
      EXPECT_EQ((reach > 0).sum().item<std::int64_t>(), rb->output->size()) << "k=" << g.k;
    }
}

TEST(SparseVsDense, ShortcutIsDenseOneByOneStrideTwo) {
  torch::manual_seed(3);
  auto sites = randomSites(1, 14, 14, 50, 5);
  RulebookCache cache;
  auto rb = cache.get(sites, RulebookCache::Kind::kShortcut, 3, 2);
  auto main = cache.get(sites, RulebookCache::Kind::kStrided, 3, 2, 1);
  EXPECT_EQ(rb->output, main->output);  // same sites as the main path, one rulebook build
  auto x = torch::randn({sites->size(), 2}, torch::kDouble);
  auto w = torch::randn({1, 2, 3}, torch::kDouble);
  auto dense = F::conv2d(toDense(x, *sites), denseWeight(w, 1), F::Conv2dFuncOptions().stride(2));
  EXPECT_LT((sparseConv(x, w, *rb) - atSites(dense, *rb->output)).abs().max().item<double>(), 1e-12);
}

TEST(SparseVsDense, PoolingEqualsDenseOverActiveInputs) {
  torch::manual_seed(4);
  auto sites = randomSites(2, 12, 12, 35, 13);
  auto rb = stridedRulebook(sites, 3, 2, 1);
  auto x = torch::randn({sites->size(), 3}, torch::kDouble);
  auto mask = toDense(torch::ones({sites->size(), 1}, torch::kDouble), *sites);
  auto pool = F::AvgPool2dFuncOptions(3).stride(2).padding(1).count_include_pad(true);
  // Max over active inputs: dense max pool with inactive pixels at -inf.
  auto dense_inf = toDense(x, *sites).masked_fill(mask == 0, -std::numeric_limits<double>::infinity());
  auto dense_max = F::max_pool2d(dense_inf, F::MaxPool2dFuncOptions(3).stride(2).padding(1));
  EXPECT_LT((sparseMaxPool(x, *rb) - atSites(dense_max, *rb->output)).abs().max().item<double>(), 1e-12);
  // Mean over active inputs: dense sum / dense count.
  auto dense_mean = F::avg_pool2d(toDense(x, *sites), pool) / F::avg_pool2d(mask, pool);
  EXPECT_LT((sparseAvgPool(x, *rb) - atSites(dense_mean, *rb->output)).abs().max().item<double>(), 1e-12);
}

TEST(SparseVsDense, GlobalPoolsPerImage) {
  torch::manual_seed(5);
  auto sites = std::make_shared<SiteSet>(3, 5, 5, std::vector<Site>{{0, 1, 1}, {2, 0, 0}, {2, 4, 4}, {2, 2, 3}});
  auto x = torch::randn({4, 2}, torch::kDouble);
  auto avg = globalAvgPool(x, *sites), mx = globalMaxPool(x, *sites);
  EXPECT_TRUE(torch::allclose(avg[0], x[0]));
  EXPECT_EQ(avg[1].abs().sum().item<double>(), 0.0);  // image without sites
  EXPECT_TRUE(torch::allclose(avg[2], x.slice(0, 1, 4).mean(0)));
  EXPECT_TRUE(torch::allclose(mx[2], std::get<0>(x.slice(0, 1, 4).max(0))));
}

TEST(IndexSum, EqualsRowWiseIndexAddToTheBitAndItsGradient) {
  torch::manual_seed(8);
  for (std::int64_t channels : {1, 3}) {
    // Many rows into few, repeated in any order: each sum's order is the rows'.
    const auto index = torch::randint(0, 5, {400}, torch::kLong);
    for (auto type : {torch::kFloat, torch::kDouble}) {
      const auto values = torch::randn({400, channels}, type);
      const auto expected = torch::zeros({6, channels}, values.options()).index_add(0, index, values);
      EXPECT_TRUE(torch::equal(indexSum(values, index, 6), expected));
    }
    const auto few = index.slice(0, 0, 60);
    expectGradientsMatch([&](const auto& in) { return indexSum(in[0], few, 6); }, {torch::randn({60, channels})});
  }
  EXPECT_THROW(indexSum(torch::zeros({4, 2}), torch::zeros({3}, torch::kLong), 2), c10::Error);
}

TEST(GradCheck, SubmanifoldConv) {
  torch::manual_seed(6);
  auto sites = randomSites(2, 7, 6, 14, 3);
  auto rb = submanifoldRulebook(sites, 3);
  for (int c_in : {2, 30})  // im2col and per-offset GEMM paths
    expectGradientsMatch([&](const auto& in) { return sparseConv(in[0], in[1], *rb); },
                         {torch::randn({sites->size(), c_in}), torch::randn({9, c_in, 3})});
}

TEST(GradCheck, StridedConv) {
  torch::manual_seed(7);
  auto sites = randomSites(2, 9, 8, 16, 4);
  auto rb = stridedRulebook(sites, 3, 2, 1);
  for (int c_in : {2, 30})
    expectGradientsMatch([&](const auto& in) { return sparseConv(in[0], in[1], *rb); },
                         {torch::randn({sites->size(), c_in}), torch::randn({9, c_in, 3})});
  auto shortcut = singleOffsetRulebook(*rb, 4);
  expectGradientsMatch([&](const auto& in) { return sparseConv(in[0], in[1], *shortcut); },
                       {torch::randn({sites->size(), 2}), torch::randn({1, 2, 3})});
}

TEST(GradCheck, Pooling) {
  torch::manual_seed(8);
  auto sites = randomSites(2, 9, 9, 20, 5);
  auto rb = stridedRulebook(sites, 3, 2, 1);
  auto x = torch::randn({sites->size(), 3});
  expectGradientsMatch([&](const auto& in) { return sparseMaxPool(in[0], *rb); }, {x});
  expectGradientsMatch([&](const auto& in) { return sparseAvgPool(in[0], *rb); }, {x});
  expectGradientsMatch([&](const auto& in) { return globalMaxPool(in[0], *sites); }, {x});
  expectGradientsMatch([&](const auto& in) { return globalAvgPool(in[0], *sites); }, {x});
  expectGradientsMatch([&](const auto& in) { return toDense(in[0], *sites); }, {x});
}

TEST(GradCheck, ChainedLayersWithReluAndResidual) {
  torch::manual_seed(9);
  auto sites = randomSites(1, 10, 10, 25, 6);
  RulebookCache cache;
  auto subm = cache.get(sites, RulebookCache::Kind::kSubmanifold, 3);
  auto down = cache.get(sites, RulebookCache::Kind::kStrided, 3, 2, 1);
  expectGradientsMatch(
      [&](const auto& in) {
        auto h = torch::relu(sparseConv(in[0], in[1], *subm)) + in[0];
        return globalAvgPool(sparseConv(h, in[2], *down), *down->output);
      },
      {torch::randn({sites->size(), 2}), torch::randn({9, 2, 2}), torch::randn({9, 2, 3})});
}

}  // namespace
}  // namespace dss::sparse
