// One Adam step over several parameter tensors in ONE parallel region (torch.optim.Adam's update without
// weight decay or amsgrad, as its fused CPU kernel computes it in float32).
//
// torch's fused Adam runs one kernel, and one OpenMP region, per parameter group; the Gaussians have six
// groups (one learning rate each), so six regions per training iteration, each of which must wake the
// OpenMP team (go_pipeline/openmp.py). Here the elements of all tensors are cut into chunks that one region
// shares out. Elementwise, so the result does not depend on the thread count.

#include <torch/extension.h>

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace {

struct Chunk {
  int tensor;
  int64_t begin, end;
};

}  // namespace

// params, grads, exp_avgs, exp_avg_sqs: float32 contiguous CPU tensors of matching sizes (updated in place);
// lrs and steps (the step count after this update, >= 1): one per tensor.
void adam_step(std::vector<torch::Tensor> params, std::vector<torch::Tensor> grads,
               std::vector<torch::Tensor> exp_avgs, std::vector<torch::Tensor> exp_avg_sqs,
               std::vector<double> lrs, std::vector<double> steps, double beta1, double beta2, double eps) {
  const size_t n = params.size();
  TORCH_CHECK(grads.size() == n && exp_avgs.size() == n && exp_avg_sqs.size() == n && lrs.size() == n &&
                  steps.size() == n,
              "adam_step: one grad, moment pair, learning rate and step count per parameter");
  constexpr int64_t kChunk = 1 << 14;
  std::vector<Chunk> chunks;
  for (size_t t = 0; t < n; ++t) {
    for (const auto* x : {&params[t], &grads[t], &exp_avgs[t], &exp_avg_sqs[t]})
      TORCH_CHECK(x->scalar_type() == torch::kFloat32 && x->device().is_cpu() && x->is_contiguous() &&
                      x->numel() == params[t].numel(),
                  "adam_step: tensors must be contiguous float32 CPU tensors of the parameter's size");
    TORCH_CHECK(steps[t] >= 1.0, "adam_step: step counts start at 1");
    for (int64_t b = 0; b < params[t].numel(); b += kChunk)
      chunks.push_back({static_cast<int>(t), b, std::min(params[t].numel(), b + kChunk)});
  }
  // per tensor: step size lr / (1 - beta1^t) and 1 / sqrt(1 - beta2^t), in float as torch's kernel uses them
  std::vector<float> step_size(n), inv_bc2_sqrt(n);
  for (size_t t = 0; t < n; ++t) {
    step_size[t] = static_cast<float>(lrs[t] / (1.0 - std::pow(beta1, steps[t])));
    inv_bc2_sqrt[t] = static_cast<float>(1.0 / std::sqrt(1.0 - std::pow(beta2, steps[t])));
  }
  // 1 - beta in double first: 1 - float(0.999) is off by 1.3e-5 relative
  const float omb1 = static_cast<float>(1.0 - beta1), omb2 = static_cast<float>(1.0 - beta2);
  const float b2 = static_cast<float>(beta2), e = static_cast<float>(eps);
  at::parallel_for(0, static_cast<int64_t>(chunks.size()), 1, [&](int64_t c0, int64_t c1) {
    for (int64_t c = c0; c < c1; ++c) {
      const Chunk& ch = chunks[c];
      float* p = params[ch.tensor].data_ptr<float>();
      const float* g = grads[ch.tensor].data_ptr<float>();
      float* m = exp_avgs[ch.tensor].data_ptr<float>();
      float* v = exp_avg_sqs[ch.tensor].data_ptr<float>();
      const float ss = step_size[ch.tensor], ib = inv_bc2_sqrt[ch.tensor];
#pragma omp simd
      for (int64_t i = ch.begin; i < ch.end; ++i) {
        const float gi = g[i];
        const float mi = m[i] + omb1 * (gi - m[i]);  // lerp, as exp_avg.lerp_(grad, 1 - beta1)
        const float vi = b2 * v[i] + omb2 * gi * gi;
        m[i] = mi;
        v[i] = vi;
        p[i] -= ss * mi / (std::sqrt(vi) * ib + e);
      }
    }
  });
}
