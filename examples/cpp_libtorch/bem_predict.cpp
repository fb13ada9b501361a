// bem_predict.cpp: load the exported TorchScript BEM predictor (bem_predictor.pt) with the
// libtorch that ships inside the torch wheel, and call bem_mean, forward and forward_latent
// (eq. 12, 14, B1).
//
//   bem_predict PREDICTOR.pt [x_1 ... x_3m]     (default: x = 0, the upright rest state)
//
// Prints the metadata's robot and input columns, then "bem_mean <value>", "forward <mean> <std>"
// (std: the calibrated band), "forward_latent <mean> <latent std>" (artifacts with that method,
// i.e. written since the band) (rad, %.17g), and the microseconds per bem_mean call (median of
// 2000, one thread).
#include <ATen/Parallel.h>
#include <torch/script.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>
#include <vector>

int main(int argc, char **argv)
{
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s PREDICTOR.pt [x_1 ... x_3m]\n", argv[0]);
        return 2;
    }
    at::set_num_threads(1);
    torch::jit::Module module;
    try {
        module = torch::jit::load(argv[1]);
    } catch (const c10::Error &e) {
        std::fprintf(stderr, "%s: cannot load: %s\n", argv[1], e.what());
        return 2;
    }
    std::string meta = module.get_method("metadata")({}).toStringRef();
    std::printf("metadata %s\n", meta.c_str());
    // the width 3m from the metadata's "m" (no JSON parser needed for one integer)
    auto pos = meta.find("\"m\":");
    int m = pos == std::string::npos ? 1 : std::atoi(meta.c_str() + pos + 4);
    std::vector<double> values(3 * m, 0.0);
    for (int i = 2; i < argc && i - 2 < 3 * m; ++i) values[i - 2] = std::atof(argv[i]);
    torch::Tensor x = torch::from_blob(values.data(), {1, 3 * m}, torch::kFloat64).clone();
    torch::NoGradGuard no_grad;
    try {
        double mean = module.get_method("bem_mean")({x}).toTensor().item<double>();
        auto out = module.forward({x}).toTuple();
        std::printf("bem_mean %.17g\n", mean);
        std::printf("forward %.17g %.17g\n", out->elements()[0].toTensor().item<double>(), out->elements()[1].toTensor().item<double>());
        if (auto latent = module.find_method("forward_latent")) {
            auto lat = (*latent)({x}).toTuple();
            std::printf("forward_latent %.17g %.17g\n", lat->elements()[0].toTensor().item<double>(),
                        lat->elements()[1].toTensor().item<double>());
        }
    } catch (const std::exception &e) {   // e.g. a non-finite input (torch::jit::JITException): "ValueError: BEMPredictor.bem_mean: ..."
        std::fprintf(stderr, "error: %s\n", e.what());
        return 1;
    }
    auto method = module.get_method("bem_mean");
    std::vector<double> us;
    for (int r = 0; r < 2200; ++r) {
        auto t0 = std::chrono::steady_clock::now();
        method({x});
        auto t1 = std::chrono::steady_clock::now();
        if (r >= 200) us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    }
    std::nth_element(us.begin(), us.begin() + us.size() / 2, us.end());
    std::printf("bem_mean_us %.3f\n", us[us.size() / 2]);
    return 0;
}
