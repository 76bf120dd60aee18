#include "held_out.h"

#include <algorithm>
#include <stdexcept>

namespace dss {

std::vector<HeldOutPrediction> predictHeldOut(const Model& model, const TrainingSet& data, std::size_t max_samples,
                                              const std::string& what, const SampleProgress& progress) {
  if (data.size() == 0 || max_samples == 0) throw std::invalid_argument(what + ": no samples");
  const InputSpec& a = data.spec();
  const InputSpec& b = model.meta.input;
  if (a.width_px != b.width_px || a.height_px != b.height_px || a.max_code != b.max_code ||
      a.threshold_dn != b.threshold_dn || a.black_level_dn != b.black_level_dn)
    throw std::invalid_argument(what + ": the samples were not encoded with the model's input spec");
  std::vector<const SparseSample*> picked;
  const std::size_t n = std::min(data.size(), max_samples);
  for (std::size_t i = 0; i < n; ++i) picked.push_back(&data.samples()[i * data.size() / n]);
  // In chunks, for the progress: a multiple of the model's passes, so the same predictions as at once.
  constexpr std::size_t kChunk = 256;
  std::vector<Prediction> predictions;
  predictions.reserve(picked.size());
  if (progress) progress(0, picked.size());
  for (std::size_t first = 0; first < picked.size(); first += kChunk) {
    const std::vector<const SparseSample*> chunk(
        picked.begin() + static_cast<std::ptrdiff_t>(first),
        picked.begin() + static_cast<std::ptrdiff_t>(std::min(picked.size(), first + kChunk)));
    const std::vector<Prediction> p = model.predictSamples(chunk);
    predictions.insert(predictions.end(), p.begin(), p.end());
    if (progress) progress(predictions.size(), picked.size());
  }
  std::vector<HeldOutPrediction> out;
  for (std::size_t k = 0; k < picked.size(); ++k)
    if (predictions[k].active_sites > 0 && predictions[k].declined.empty())  // else "no_sun" or declined
      out.push_back({picked[k], predictions[k]});
  return out;
}

}  // namespace dss
