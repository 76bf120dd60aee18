#include "held_out.h"

#include <algorithm>
#include <stdexcept>

namespace dss {

std::vector<HeldOutPrediction> predictHeldOut(const Model& model, const TrainingSet& data, std::size_t max_samples,
                                              const std::string& what) {
  if (data.size() == 0 || max_samples == 0) throw std::invalid_argument(what + ": no samples");
  const InputSpec& a = data.spec();
  const InputSpec& b = model.meta.input;
  if (a.width_px != b.width_px || a.height_px != b.height_px || a.max_code != b.max_code ||
      a.threshold_dn != b.threshold_dn || a.black_level_dn != b.black_level_dn)
    throw std::invalid_argument(what + ": the samples were not encoded with the model's input spec");
  std::vector<const SparseSample*> picked;
  const std::size_t n = std::min(data.size(), max_samples);
  for (std::size_t i = 0; i < n; ++i) picked.push_back(&data.samples()[i * data.size() / n]);
  const std::vector<Prediction> predictions = model.predictSamples(picked);
  std::vector<HeldOutPrediction> out;
  for (std::size_t k = 0; k < picked.size(); ++k)
    if (predictions[k].active_sites > 0 && predictions[k].declined.empty())  // else "no_sun" or declined
      out.push_back({picked[k], predictions[k]});
  return out;
}

}  // namespace dss
