// SSCNN model: batch independence, save/load round trip, rejected files,
// inference over mirror images, and a tiny network that overfits simulated images.
#include <gtest/gtest.h>
#include <torch/optim/adam.h>

#include <cstdio>
#include <fstream>
#include <opencv2/core.hpp>
#include <set>

#include "digital_sun_sensor/model/model.h"
#include "digital_sun_sensor/model/sparse_input.h"
#include "digital_sun_sensor/sim/dataset_generator.h"
#include "digital_sun_sensor/sparse/ops.h"
#include "digital_sun_sensor/sparse/threads.h"

namespace dss {
namespace {

SensorConfig shipped(const std::string& name) {
  return loadSensorConfig(std::string(DSS_SOURCE_DIR) + "/config/sensors/" + name + ".yaml");
}

// A few simulated thesis_sa images (shared by the tests: rendering warms a cache).
const std::vector<DatasetItem>& images() {
  static const std::vector<DatasetItem> items = [] {
    DatasetSpec spec;
    spec.count = 8;
    spec.seed = 5;
    std::vector<DatasetItem> out;
    DatasetGenerator(shipped("thesis_sa"), spec).run([&](const DatasetItem& i) { out.push_back(i); });
    return out;
  }();
  return items;
}

std::vector<cv::Mat> imageList() {
  std::vector<cv::Mat> list;
  for (const auto& i : images()) list.push_back(i.image);
  return list;
}

std::string expectModelError(const std::string& bytes, const SensorConfig* expected = nullptr) {
  try {
    deserializeModel(bytes, "test.dssmodel", expected);
  } catch (const ModelError& e) {
    return e.what();
  }
  ADD_FAILURE() << "accepted a bad model file";
  return {};
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

TEST(SparseInput, EncodesThresholdedImage) {
  const SensorConfig c = shipped("thesis_sa");
  const InputSpec spec = inputSpecFor(c);
  const auto input = encodeImages(imageList(), spec);
  ASSERT_EQ(input.sites->batchSize(), 8);
  for (int n : input.sites->countsPerImage()) EXPECT_GT(n, 20);
  EXPECT_LE(input.features.slice(1, 0, 1).max().item<float>(), 1.0f);
  EXPECT_GT(input.features.slice(1, 0, 1).min().item<float>(), 0.0f);
  EXPECT_LE(input.features.slice(1, 1, 3).abs().max().item<float>(), 1.0f);
  InputSpec few = spec;
  few.max_sites = 10;
  for (int n : encodeImages(imageList(), few).sites->countsPerImage()) EXPECT_EQ(n, 10);
  cv::Mat wrong(256, 512, CV_8U, cv::Scalar(0));
  try {
    encodeImages({images()[0].image, wrong}, spec);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_TRUE(contains(e.what(), "image 1 of the batch: image is 512x256 px but the sensor has 512x512")) << e.what();
  }
  EXPECT_THROW(encodeImages({cv::Mat(512, 512, CV_32F)}, spec), std::invalid_argument);
}

TEST(SparseInput, SiteImageHoldsWhatTheSitesHold) {
  const InputSpec spec = inputSpecFor(shipped("thesis_sa"));
  InputSpec few = spec;
  few.max_sites = 10;  // the brightest ten, as the encoder keeps them
  for (const InputSpec& s : {spec, few}) {
    const auto input = encodeImages(imageList(), s);
    const auto value = input.features.select(1, 0).to(torch::kDouble);
    const double dn_per_value = std::max(1.0, s.max_code - s.black_level_dn);
    std::vector<cv::Mat> expected;
    for (std::size_t b = 0; b < imageList().size(); ++b) expected.push_back(cv::Mat::zeros(512, 512, CV_8U));
    const auto& sites = input.sites->sites();
    for (std::size_t k = 0; k < sites.size(); ++k)
      expected[static_cast<std::size_t>(sites[k].batch)].at<std::uint8_t>(sites[k].y, sites[k].x) =
          static_cast<std::uint8_t>(
              std::lround(value[static_cast<std::int64_t>(k)].item<double>() * dn_per_value + s.black_level_dn));
    const auto counts = input.sites->countsPerImage();
    for (std::size_t b = 0; b < expected.size(); ++b) {
      int count = -1;
      const cv::Mat made = siteImage(imageList()[b], s, count);
      ASSERT_EQ(made.type(), CV_8U);
      EXPECT_EQ(cv::countNonZero(made != expected[b]), 0) << b << " of max_sites " << s.max_sites;
      EXPECT_EQ(count, counts[b]) << b;
    }
  }
  int count = 0;
  EXPECT_THROW(siteImage(cv::Mat(256, 512, CV_8U, cv::Scalar(0)), spec, count), std::invalid_argument);
}

TEST(Sscnn, BatchOfDifferentSiteCountsEqualsSingleImages) {
  const SensorConfig c = shipped("thesis_sa");
  Model m = createModel(c, "resnet10_w16", 3);
  m.net->eval();
  m.net->to(torch::kDouble);
  const cv::Mat empty(512, 512, CV_8U, cv::Scalar(0));
  cv::Mat one = empty.clone();
  one.at<std::uint8_t>(0, 511) = 200;  // a single site on the border
  const std::vector<cv::Mat> batch{images()[0].image, empty, one, images()[1].image};
  torch::NoGradGuard no_grad;
  const auto together = m.net->forward(encodeImages(batch, m.meta.input, torch::kDouble));
  for (std::size_t b = 0; b < batch.size(); ++b) {
    const auto alone = m.net->forward(encodeImages({batch[b]}, m.meta.input, torch::kDouble));
    const auto i = static_cast<std::int64_t>(b);
    EXPECT_LT((together.angles[i] - alone.angles[0]).abs().max().item<double>(), 1e-12) << b;
    EXPECT_LT((together.class_logits[i] - alone.class_logits[0]).abs().max().item<double>(), 1e-12) << b;
    EXPECT_TRUE(torch::isfinite(alone.log_variance).all().item<bool>()) << b;
  }
}

TEST(ModelFile, RoundTripIsBitExact) {
  const SensorConfig c = shipped("thesis_sa");
  const Model m = createModel(c, "resnet10_w16", 4);
  m.net->eval();
  const std::string path = ::testing::TempDir() + "/roundtrip.dssmodel";
  saveModel(m, path);
  const Model loaded = loadModel(path, &c);
  EXPECT_EQ(loaded.meta.arch.name, "resnet10_w16");
  EXPECT_EQ(loaded.meta.sensor_name, "thesis_sa");
  EXPECT_EQ(loaded.meta.input.threshold_dn, m.meta.input.threshold_dn);
  torch::NoGradGuard no_grad;
  const auto input = encodeImages(imageList(), m.meta.input);
  const auto a = m.net->forward(input), b = loaded.net->forward(input);
  EXPECT_TRUE(torch::equal(a.angles, b.angles));
  EXPECT_TRUE(torch::equal(a.log_variance, b.log_variance));
  EXPECT_TRUE(torch::equal(a.class_logits, b.class_logits));
  // Saving over an existing file leaves no temp file behind.
  saveModel(loaded, path);
  std::ifstream tmp(path + ".tmp." + std::to_string(::getpid()));
  EXPECT_FALSE(tmp.good());
  std::remove(path.c_str());
}

// A constant sigma (sigma calibration's choice when the head's shape is
// uninformative) is what every image gets, whatever its content.
TEST(Sscnn, ConstantSigmaIsPredictedForEveryImage) {
  Model m = createModel(shipped("thesis_sa"), "resnet10_w16", 4);
  m.net->eval();
  m.setConstantSigma(1.3e-5, 2.6e-5);
  for (const Prediction& p : m.predict(imageList())) {
    EXPECT_NEAR(std::sqrt(p.alpha_variance_rad2), 1.3e-5, 1e-10);
    EXPECT_NEAR(std::sqrt(p.beta_variance_rad2), 2.6e-5, 1e-10);
  }
  EXPECT_THROW(m.setConstantSigma(0.0, 1e-5), std::invalid_argument);
}

// With a lit-site law, each image's constant sigma is scaled by
// (lit sites / reference)^-exponent; the law survives the model file, and a
// bad one is refused by name.
TEST(Sscnn, SiteSigmaLawScalesTheConstantPerImage) {
  const SensorConfig c = shipped("thesis_sa");
  Model m = createModel(c, "resnet10_w16", 4);
  m.net->eval();
  m.setConstantSigma(1.3e-5, 2.6e-5);
  m.meta.sigma_site_law = {0.5, 100.0};
  const Model loaded = deserializeModel(serializeModel(m), "law", &c);
  EXPECT_EQ(loaded.meta.sigma_site_law.exponent, 0.5);
  EXPECT_EQ(loaded.meta.sigma_site_law.reference_sites, 100.0);
  std::set<int> counts;
  for (const Prediction& p : loaded.predict(imageList())) {
    ASSERT_GT(p.active_sites, 0);
    counts.insert(p.active_sites);
    const double factor = std::sqrt(100.0 / p.active_sites);
    EXPECT_NEAR(std::sqrt(p.alpha_variance_rad2), 1.3e-5 * factor, 1e-10 * factor);
    EXPECT_NEAR(std::sqrt(p.beta_variance_rad2), 2.6e-5 * factor, 1e-10 * factor);
  }
  EXPECT_GT(counts.size(), 1u);  // the images differ, so the sigmas do
  std::string yaml = metadataToYaml(m.meta);
  const std::size_t at = yaml.find("reference_sites: 100");
  ASSERT_NE(at, std::string::npos);
  yaml.replace(at, 20, "reference_sites: -1");
  try {
    metadataFromYaml(yaml, "bad law");
    ADD_FAILURE() << "a negative reference was accepted";
  } catch (const ModelError& e) {
    EXPECT_NE(std::string(e.what()).find("sigma_site_law"), std::string::npos) << e.what();
  }
}

// A metadata key the format does not have is refused with its path, at the
// top level and inside a section; the metadata as written reads back.
TEST(ModelFile, MetadataRejectsUnknownKeys) {
  const Model m = createModel(shipped("thesis_ma"), "resnet10_w16", 4);
  const std::string yaml = metadataToYaml(m.meta);
  EXPECT_NO_THROW(metadataFromYaml(yaml, "good"));
  auto errorOf = [](const std::string& text) -> std::string {
    try {
      metadataFromYaml(text, "m.dssmodel");
    } catch (const ModelError& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_TRUE(contains(errorOf(yaml + "\nangle_scale: 1\n"), "m.dssmodel: metadata: angle_scale: unknown key"))
      << errorOf(yaml + "\nangle_scale: 1\n");
  std::string nested = yaml;
  const std::size_t at = nested.find("lattice_rows:");
  ASSERT_NE(at, std::string::npos);
  nested.insert(at, "lattice_row: 3\n  ");
  EXPECT_TRUE(contains(errorOf(nested), "arch.lattice_row: unknown key")) << errorOf(nested);
}

// The w-weighted centroid of each image's sites (normalized x, y).
torch::Tensor siteCentroid(const sparse::SparseTensor& input, const torch::Tensor& w) {
  const auto index = sparse::batchIndex(*input.sites);
  const auto sum = [&](const torch::Tensor& v) {
    return torch::zeros({input.sites->batchSize(), v.size(1)}, v.options()).index_add(0, index, v);
  };
  return sum(w * input.features.slice(1, 1, 3)) / sum(w);
}

// Untrained, the centroid branch is the plain centre of the lit sites
// (learned weights) or their intensity-weighted centroid (value weighting,
// and intensity weighting, which stays so whatever the branch's weights),
// which the linear prior maps to the angles; the sparse and dense forward
// passes agree, and the choice survives the model file.
TEST(Sscnn, CentroidWeightingStartsAsPlainOrIntensityWeightedCentroid) {
  const SensorConfig c = shipped("thesis_sa");
  ArchSpec arch = archPreset("resnet10_w16", c.numSubFovClasses());
  const Model plain = createModel(c, arch, 4);
  arch.centroid_weighting = CentroidWeighting::kValue;
  const Model weighted = createModel(c, arch, 4);
  EXPECT_EQ(deserializeModel(serializeModel(weighted), "weighted", &c).meta.arch.centroid_weighting,
            CentroidWeighting::kValue);
  EXPECT_EQ(deserializeModel(serializeModel(plain), "plain", &c).meta.arch.centroid_weighting,
            CentroidWeighting::kLearned);
  arch.centroid_weighting = CentroidWeighting::kIntensity;
  const Model intensity = createModel(c, arch, 4);
  EXPECT_EQ(deserializeModel(serializeModel(intensity), "intensity", &c).meta.arch.centroid_weighting,
            CentroidWeighting::kIntensity);

  torch::NoGradGuard no_grad;
  const auto input = encodeImages(imageList(), plain.meta.input, torch::kDouble);
  plain.net->to(torch::kDouble);
  weighted.net->to(torch::kDouble);
  const auto value = input.features.slice(1, 0, 1);
  auto centroid = [&](const torch::Tensor& w) { return siteCentroid(input, w); };
  const auto plain_centroid = centroid(torch::ones_like(value)), weighted_centroid = centroid(value);
  ASSERT_GT((plain_centroid - weighted_centroid).abs().max().item<double>(), 1e-4);  // the test tells them apart
  const auto plain_angles = plain.net->forward(input).angles, weighted_angles = weighted.net->forward(input).angles;
  const auto slope = plain_angles[0] / plain_centroid[0];  // the linear prior, per axis
  // (the branch's denominator carries a 1e-6 guard against empty images)
  EXPECT_LT((plain_angles - plain_centroid * slope).abs().max().item<double>(), 1e-7);
  EXPECT_LT((weighted_angles - weighted_centroid * slope).abs().max().item<double>(), 1e-7);
  const auto dense = encodeImagesDense({images()[0].image}, weighted.meta.input).to(torch::kDouble);
  EXPECT_LT((weighted.net->forwardDense(dense).angles[0] - weighted_angles[0]).abs().max().item<double>(), 1e-9);

  intensity.net->to(torch::kDouble);
  for (const Model* m : {&weighted, &intensity})
    for (auto& p : m->net->named_parameters())
      if (p.key().rfind("centroid_conv", 0) == 0) p.value().normal_(0.0, 1.0);
  EXPECT_GT((weighted.net->forward(input).angles - weighted_angles).abs().max().item<double>(), 1e-6);
  const auto intensity_angles = intensity.net->forward(input).angles;
  EXPECT_LT((intensity_angles - weighted_angles).abs().max().item<double>(), 1e-12);
  EXPECT_LT((intensity.net->forwardDense(dense).angles[0] - weighted_angles[0]).abs().max().item<double>(), 1e-9);
}

// With a value saturation S the intensity-weighted centroid weighs each site
// by v / (1 + S v): the angles move to that centroid (through the same linear
// prior), the dense pass agrees, the file keeps S and refuses a negative one.
TEST(Sscnn, ValueSaturationWeighsSitesBySaturatedValue) {
  const SensorConfig c = shipped("thesis_sa");
  ArchSpec arch = archPreset("resnet10_w16", c.numSubFovClasses());
  arch.centroid_weighting = CentroidWeighting::kIntensity;
  const Model plain = createModel(c, arch, 4);
  arch.value_saturation = 2.0;
  const Model saturated = createModel(c, arch, 4);
  EXPECT_EQ(deserializeModel(serializeModel(saturated), "saturated", &c).meta.arch.value_saturation, 2.0);
  EXPECT_EQ(deserializeModel(serializeModel(plain), "plain", &c).meta.arch.value_saturation, 0.0);
  std::string yaml = metadataToYaml(saturated.meta);
  const auto at = yaml.find("value_saturation: 2");
  ASSERT_NE(at, std::string::npos) << yaml;
  yaml.replace(at, std::string("value_saturation: 2").size(), "value_saturation: -1");
  EXPECT_THROW(metadataFromYaml(yaml, "test"), ModelError);

  torch::NoGradGuard no_grad;
  const auto input = encodeImages(imageList(), plain.meta.input, torch::kDouble);
  plain.net->to(torch::kDouble);
  saturated.net->to(torch::kDouble);
  const auto value = input.features.slice(1, 0, 1);
  auto centroid = [&](const torch::Tensor& w) { return siteCentroid(input, w); };
  const auto weighted_centroid = centroid(value), saturated_centroid = centroid(value / (1.0 + 2.0 * value));
  ASSERT_GT((weighted_centroid - saturated_centroid).abs().max().item<double>(), 1e-5);  // the test tells them apart
  const auto plain_angles = plain.net->forward(input).angles;
  const auto saturated_angles = saturated.net->forward(input).angles;
  const auto slope = plain_angles[0] / weighted_centroid[0];
  EXPECT_LT((plain_angles - weighted_centroid * slope).abs().max().item<double>(), 1e-7);
  EXPECT_LT((saturated_angles - saturated_centroid * slope).abs().max().item<double>(), 1e-7);
  const auto dense = encodeImagesDense({images()[0].image}, saturated.meta.input).to(torch::kDouble);
  EXPECT_LT((saturated.net->forwardDense(dense).angles[0] - saturated_angles[0]).abs().max().item<double>(), 1e-9);
}

// With feature corrections off the angles are a function of the spot
// position alone: whatever the MLP's output layer holds, they do not move,
// while with them on they do; the choice survives the model file.
TEST(Sscnn, FeatureCorrectionsOffLeaveTheAnglesToThePosition) {
  const SensorConfig c = shipped("thesis_sa");
  ArchSpec arch = archPreset("resnet10_w16", c.numSubFovClasses());
  const Model with = createModel(c, arch, 4);
  arch.feature_corrections = false;
  const Model without = createModel(c, arch, 4);
  EXPECT_FALSE(deserializeModel(serializeModel(without), "without", &c).meta.arch.feature_corrections);
  EXPECT_TRUE(deserializeModel(serializeModel(with), "with", &c).meta.arch.feature_corrections);

  torch::NoGradGuard no_grad;
  const auto input = encodeImages(imageList(), with.meta.input);
  const auto before_with = with.net->forward(input).angles, before_without = without.net->forward(input).angles;
  for (const Model* m : {&with, &without})
    for (auto& p : m->net->named_parameters())
      if (p.key().rfind("output.", 0) == 0) p.value().normal_(0.0, 1.0);
  EXPECT_GT((with.net->forward(input).angles - before_with).abs().max().item<double>(), 1e-4);
  EXPECT_EQ((without.net->forward(input).angles - before_without).abs().max().item<double>(), 0.0);
}

TEST(ModelFile, BatchNormVariantKeepsItsRunningStatistics) {
  const SensorConfig c = shipped("thesis_sa");
  ArchSpec arch = archPreset("resnet10_w16", c.numSubFovClasses());
  arch.batch_norm = true;
  Model m;
  m.meta = metadataFor(c, arch);
  m.net = std::make_shared<SscnnNetImpl>(m.meta.arch);
  const auto input = encodeImages(imageList(), m.meta.input);
  m.net->train();
  m.net->forward(input).angles.sum().backward();  // updates the running statistics
  m.net->eval();
  const Model loaded = deserializeModel(serializeModel(m), "bn", &c);
  EXPECT_TRUE(loaded.meta.arch.batch_norm);
  torch::NoGradGuard no_grad;
  EXPECT_TRUE(torch::equal(m.net->forward(input).angles, loaded.net->forward(input).angles));
  EXPECT_TRUE(torch::isfinite(loaded.net->forward(input).angles).all().item<bool>());
}

TEST(ModelFile, RejectsCorruptTruncatedWrongArchitectureAndWrongSensor) {
  const SensorConfig c = shipped("thesis_sa");
  const Model m = createModel(c, "resnet10_w16");
  const std::string good = serializeModel(m);
  EXPECT_NO_THROW(deserializeModel(good, "good", &c));

  EXPECT_TRUE(contains(expectModelError(""), "bad magic or too short"));
  EXPECT_TRUE(contains(expectModelError("not a model at all, just some text to fill forty bytes"), "bad magic"));
  EXPECT_TRUE(contains(expectModelError(good.substr(0, good.size() / 2)), "truncated"));
  EXPECT_TRUE(contains(expectModelError(good + "x"), "truncated or padded"));
  std::string flipped = good;
  flipped[flipped.size() / 2] ^= 0x40;
  EXPECT_TRUE(contains(expectModelError(flipped), "checksum mismatch"));

  // Metadata says resnet10_w16, weights are another architecture's.
  Model mixed = m;
  mixed.net = createModel(c, "resnet18_w32").net;
  EXPECT_TRUE(contains(expectModelError(serializeModel(mixed)), "tensor 'stem.weight' has shape"));

  // A model for thesis_sa refuses wide_ma (and thesis_ma).
  const SensorConfig wide = shipped("wide_ma");
  EXPECT_TRUE(contains(expectModelError(good, &wide), "made for sensor 'thesis_sa'"));
  const SensorConfig ma = shipped("thesis_ma");
  EXPECT_TRUE(contains(expectModelError(good, &ma), "number of apertures"));

  EXPECT_THROW(loadModel("/nonexistent/dir/model.dssmodel"), ModelError);
  EXPECT_THROW(createModel(c, "resnet99"), std::invalid_argument);

  // A network shape over the limits is refused before the network is built
  // (a damaged width would otherwise allocate gigabytes).
  auto withMetadata = [&](const std::string& from, const std::string& to) {
    std::string meta = metadataToYaml(m.meta);
    const auto at = meta.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    return meta.replace(at, from.size(), to);
  };
  auto metadataError = [&](const std::string& text) -> std::string {
    try {
      metadataFromYaml(text, "damaged");
    } catch (const ModelError& e) {
      return e.what();
    }
    return "";
  };
  EXPECT_TRUE(contains(metadataError(withMetadata("widths: [", "widths: [100000")), "(limit)"));
  EXPECT_TRUE(contains(metadataError(withMetadata("max_sites: ", "max_sites: 99")), "over the limits"));
}

TEST(Sscnn, TinyNetworkOverfitsSimulatedImages) {
  sparse::configureThreads(1, 2);
  const SensorConfig c = shipped("thesis_sa");
  Model m = createModel(c, "resnet10_w16", 7);
  m.net->train();
  const auto input = encodeImages(imageList(), m.meta.input);
  std::vector<float> target_values;
  std::vector<std::int64_t> classes;
  for (const auto& i : images()) {
    target_values.push_back(static_cast<float>(i.truth.alpha_rad / m.meta.angle_scale_rad));
    target_values.push_back(static_cast<float>(i.truth.beta_rad / m.meta.angle_scale_rad));
    classes.push_back(i.truth.subfov_class);
  }
  const auto target = torch::tensor(target_values).view({-1, 2});
  const auto target_class = torch::tensor(classes);
  torch::optim::Adam optimizer(m.net->parameters(), torch::optim::AdamOptions(2e-3));
  auto loss_of = [&](const SscnnOutput& out) {
    return torch::mse_loss(out.angles, target) + 0.01 * torch::cross_entropy_loss(out.class_logits, target_class);
  };
  double first = 0, last = 0;
  for (int step = 0; step < 400; ++step) {
    optimizer.zero_grad();
    auto loss = loss_of(m.net->forward(input));
    if (step == 0) first = loss.item<double>();
    loss.backward();
    optimizer.step();
    last = loss.item<double>();
  }
  EXPECT_LT(last, first / 100.0) << "loss " << first << " -> " << last;
}

// Which sensors have which mirror symmetries, and what breaks them.
TEST(InferenceSymmetry, SensorsWithAndWithoutTheSymmetry) {
  for (const char* name : {"thesis_sa", "thesis_ma", "thesis_sa_t50"}) {
    EXPECT_EQ(symmetryMismatch(shipped(name), InferenceSymmetry::kDihedral), "") << name;
    EXPECT_EQ(symmetryMismatch(shipped(name), InferenceSymmetry::kFlips), "") << name;
  }
  // wide_ma's aperture code is its own under no mirror: the diameters tell the apertures apart.
  EXPECT_TRUE(contains(symmetryMismatch(shipped("wide_ma"), InferenceSymmetry::kFlips), "no counterpart"));
  SensorConfig moved = shipped("thesis_ma");
  moved.mask.apertures[0].x_um += 1.0;
  EXPECT_TRUE(contains(symmetryMismatch(moved, InferenceSymmetry::kFlips), "aperture 0 at (-264.05, -265.05) um"));
  SensorConfig wide_detector = shipped("thesis_sa");
  wide_detector.detector.width_px = 640;
  EXPECT_EQ(symmetryMismatch(wide_detector, InferenceSymmetry::kFlips), "");
  EXPECT_TRUE(contains(symmetryMismatch(wide_detector, InferenceSymmetry::kDihedral), "not square"));
  SensorConfig narrow_field = shipped("thesis_sa");
  narrow_field.fov.beta_max_deg = 2.0;
  EXPECT_TRUE(contains(symmetryMismatch(narrow_field, InferenceSymmetry::kDihedral), "field of view"));
  // A slit: mirrored in x or y it is itself, transposed it is not; a square is itself under all.
  SensorConfig slit = shipped("thesis_sa");
  slit.mask.apertures[0].shape = ApertureShape::kRectangle;
  slit.mask.apertures[0].width_um = 40.0;
  slit.mask.apertures[0].height_um = 20.0;
  EXPECT_EQ(symmetryMismatch(slit, InferenceSymmetry::kFlips), "");
  EXPECT_NE(symmetryMismatch(slit, InferenceSymmetry::kDihedral), "");
  slit.mask.apertures[0].rotation_deg = 90.0;  // the same slit as 20 x 40 at 0
  EXPECT_EQ(symmetryMismatch(slit, InferenceSymmetry::kFlips), "");
  slit.mask.apertures[0].rotation_deg = 30.0;
  EXPECT_NE(symmetryMismatch(slit, InferenceSymmetry::kFlips), "");
  slit.mask.apertures[0].height_um = 40.0;
  slit.mask.apertures[0].rotation_deg = 0.0;
  EXPECT_EQ(symmetryMismatch(slit, InferenceSymmetry::kDihedral), "");
  EXPECT_THROW(parseInferenceSymmetry("mirror"), std::invalid_argument);
  EXPECT_EQ(parseInferenceSymmetry("dihedral"), InferenceSymmetry::kDihedral);
}

// Averaged over the mirror images, the estimate of a mirrored image is the
// mirrored estimate, exactly; a trained network alone is not equivariant. The
// model file keeps the symmetry and refuses one the sensor lacks.
TEST(InferenceSymmetry, AveragedEstimatesAreExactlyEquivariant) {
  const SensorConfig c = shipped("thesis_sa");
  Model m = loadModel(std::string(DSS_SOURCE_DIR) + "/models/thesis_sa.dssmodel", &c);
  const cv::Mat& image = images()[1].image;
  auto mirrors = [](const cv::Mat& img) {
    std::vector<cv::Mat> out;
    cv::Mat t, f;
    cv::transpose(img, t);
    for (const cv::Mat& base : {img, t}) {
      out.push_back(base.clone());
      for (int code : {1, 0, -1}) {
        cv::flip(base, f, code);
        out.push_back(f.clone());
      }
    }
    return out;
  };
  const std::vector<cv::Mat> mirrored = mirrors(image);
  const std::vector<PixelTransform> transforms = symmetryTransforms(InferenceSymmetry::kDihedral);
  ASSERT_EQ(transforms.size(), mirrored.size());
  // Largest disagreement, over the mirror images, between their estimate mapped back and the image's.
  auto disagreement = [&](const Model& model) {
    const std::vector<Prediction> p = model.predict(mirrored);
    double worst = 0.0;
    for (std::size_t g = 1; g < p.size(); ++g) {
      double alpha = p[g].alpha_rad, beta = p[g].beta_rad;
      transforms[g].unmapAngles(alpha, beta);
      worst = std::max({worst, std::abs(alpha - p[0].alpha_rad), std::abs(beta - p[0].beta_rad)});
    }
    return worst;
  };
  m.meta.inference_symmetry = InferenceSymmetry::kNone;  // the shipped file has it on
  const double alone = disagreement(m);
  m.meta.inference_symmetry = InferenceSymmetry::kDihedral;
  const double averaged = disagreement(m);
  EXPECT_GT(alone, 1e-6) << alone;  // radians
  EXPECT_LT(averaged, 1e-9) << averaged;
  // Training samples take the same path as images.
  TrainingSet set(m.meta.input);
  set.add(image, 0.0, 0.0, 0);
  const Prediction from_image = m.predict({image})[0];
  const Prediction from_sample = m.predictSamples({&set.samples()[0]})[0];
  EXPECT_NEAR(from_sample.alpha_rad, from_image.alpha_rad, 1e-9);
  EXPECT_NEAR(from_sample.beta_rad, from_image.beta_rad, 1e-9);
  EXPECT_EQ(from_sample.active_sites, from_image.active_sites);

  const Model loaded = deserializeModel(serializeModel(m), "symmetric", &c);
  EXPECT_EQ(loaded.meta.inference_symmetry, InferenceSymmetry::kDihedral);
  std::string yaml = metadataToYaml(m.meta);
  yaml.replace(yaml.find("inference_symmetry: dihedral"), 28, "inference_symmetry: mirror");
  try {
    metadataFromYaml(yaml, "edited");
    ADD_FAILURE() << "accepted an unknown symmetry";
  } catch (const ModelError& e) {
    EXPECT_TRUE(contains(e.what(), "'inference_symmetry'")) << e.what();
  }
  SensorConfig off_centre = c;
  off_centre.mask.apertures[0].x_um = 20.0;
  Model asymmetric = createModel(off_centre, "resnet10_w16", 4);
  asymmetric.meta.inference_symmetry = InferenceSymmetry::kFlips;
  EXPECT_TRUE(contains(expectModelError(serializeModel(asymmetric)), "lacks that symmetry: aperture 0"));
}

}  // namespace
}  // namespace dss
