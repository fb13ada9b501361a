// bem_predict.cpp: load the exported BEM predictor with the libtorch that ships inside the torch
// wheel and call bem_mean, forward and forward_latent (eq. 12, 14, B1). Either artifact:
//
//   bem_predictor.pt         TorchScript          torch::jit::load
//   bem_predictor_aoti.pt2   AOTInductor package  torch::inductor::AOTIModelPackageLoader, one
//                            loader per method ("model" = forward, "bem_mean", "forward_latent", ...)
//
//   bem_predict PREDICTOR [x_1 ... x_3m]     (default: x = 0, the upright rest state)
//
// Prints the metadata, then "bem_mean <value>", "forward <mean> <std>" (std: the calibrated band),
// "forward_latent <mean> <latent std>" (artifacts with that method, i.e. written since the band)
// (rad, %.17g), and the microseconds per bem_mean and per forward call (medians of 2000, one thread).
//
// The AOTInductor methods do not check their input's shape or dtype: a float32 tensor or the wrong
// width is read as if it were right. check_input() below is what a C++ caller has to check itself
// (the TorchScript module checks inside); B >= 1 and non-finite inputs are checked by both.
#include <ATen/Parallel.h>
#include <torch/csrc/inductor/aoti_package/model_package_loader.h>
#include <torch/script.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

using Method = std::function<std::vector<torch::Tensor>(const torch::Tensor &)>;

struct Predictor {
    std::string metadata;
    Method bem_mean, forward;
    std::optional<Method> forward_latent;
};

bool ends_with(const std::string &s, const std::string &tail)
{
    return s.size() >= tail.size() && s.compare(s.size() - tail.size(), tail.size(), tail) == 0;
}

// What the AOTInductor methods need and do not check: a CPU float64 tensor of shape (B, width), B >= 1,
// contiguous (row-major). The message follows the TorchScript module's.
void check_input(const torch::Tensor &x, int64_t width, const char *method)
{
    if (x.dim() != 2 || x.size(1) != width || x.size(0) == 0 || x.scalar_type() != torch::kFloat64 || !x.device().is_cpu()
        || !x.is_contiguous())
        throw std::invalid_argument(std::string("BEMPredictor.") + method + ": expected a contiguous CPU x of shape (B, "
                                    + std::to_string(width) + "), B >= 1, and dtype float64");
}

Predictor load_torchscript(const std::string &path)
{
    auto module = std::make_shared<torch::jit::Module>(torch::jit::load(path));
    auto one = [module](const char *name) -> Method {
        auto method = std::make_shared<torch::jit::Method>(module->get_method(name));
        return [method](const torch::Tensor &x) { return std::vector<torch::Tensor>{(*method)({x}).toTensor()}; };
    };
    auto two = [module](const char *name) -> Method {
        auto method = std::make_shared<torch::jit::Method>(module->get_method(name));
        return [method](const torch::Tensor &x) {
            auto out = (*method)({x}).toTuple();
            return std::vector<torch::Tensor>{out->elements()[0].toTensor(), out->elements()[1].toTensor()};
        };
    };
    Predictor p{module->get_method("metadata")({}).toStringRef(), one("bem_mean"), two("forward"), std::nullopt};
    if (module->find_method("forward_latent")) p.forward_latent = two("forward_latent");
    return p;
}

Predictor load_aoti(const std::string &path, int64_t *width)
{
    auto bem_mean = std::make_shared<torch::inductor::AOTIModelPackageLoader>(path, "bem_mean");
    auto forward = std::make_shared<torch::inductor::AOTIModelPackageLoader>(path, "model");
    auto latent = std::make_shared<torch::inductor::AOTIModelPackageLoader>(path, "forward_latent");
    std::string meta = bem_mean->get_metadata().at("bemlearn_metadata");   // the metadata() document
    auto pos = meta.find("\"m\":");
    *width = 3 * (pos == std::string::npos ? 1 : std::atoi(meta.c_str() + pos + 4));
    int64_t n = *width;
    auto wrap = [n](std::shared_ptr<torch::inductor::AOTIModelPackageLoader> loader, const char *name) -> Method {
        return [loader, n, name](const torch::Tensor &x) {
            check_input(x, n, name);
            return loader->run({x});
        };
    };
    return Predictor{meta, wrap(bem_mean, "bem_mean"), wrap(forward, "forward"), wrap(latent, "forward_latent")};
}

double median_us(const Method &method, const torch::Tensor &x)
{
    std::vector<double> us;
    for (int r = 0; r < 2200; ++r) {
        auto t0 = std::chrono::steady_clock::now();
        method(x);
        auto t1 = std::chrono::steady_clock::now();
        if (r >= 200) us.push_back(std::chrono::duration<double, std::micro>(t1 - t0).count());
    }
    std::nth_element(us.begin(), us.begin() + us.size() / 2, us.end());
    return us[us.size() / 2];
}

}  // namespace

int main(int argc, char **argv)
{
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s PREDICTOR.pt|PREDICTOR_aoti.pt2 [x_1 ... x_3m]\n", argv[0]);
        return 2;
    }
    at::set_num_threads(1);
    std::string path = argv[1];
    Predictor predictor;
    int64_t width = 0;
    try {
        if (ends_with(path, ".pt2")) {
            predictor = load_aoti(path, &width);
        } else {
            predictor = load_torchscript(path);
            auto pos = predictor.metadata.find("\"m\":");   // the width 3m from "m" (no JSON parser for one integer)
            width = 3 * (pos == std::string::npos ? 1 : std::atoi(predictor.metadata.c_str() + pos + 4));
        }
    } catch (const std::exception &e) {
        std::fprintf(stderr, "%s: cannot load: %s\n", argv[1], e.what());
        return 2;
    }
    std::printf("metadata %s\n", predictor.metadata.c_str());
    std::vector<double> values(width, 0.0);
    for (int i = 2; i < argc && i - 2 < width; ++i) values[i - 2] = std::atof(argv[i]);
    torch::Tensor x = torch::from_blob(values.data(), {1, width}, torch::kFloat64).clone();
    torch::NoGradGuard no_grad;
    try {
        double mean = predictor.bem_mean(x)[0].item<double>();
        auto out = predictor.forward(x);
        std::printf("bem_mean %.17g\n", mean);
        std::printf("forward %.17g %.17g\n", out[0].item<double>(), out[1].item<double>());
        if (predictor.forward_latent) {
            auto lat = (*predictor.forward_latent)(x);
            std::printf("forward_latent %.17g %.17g\n", lat[0].item<double>(), lat[1].item<double>());
        }
    } catch (const std::exception &e) {
        // a non-finite input: "ValueError: BEMPredictor.bem_mean: ..." (TorchScript, torch::jit::JITException)
        // or "BEMPredictor.bem_mean: x has non-finite entries ..." (AOTInductor, std::runtime_error)
        std::fprintf(stderr, "error: %s\n", e.what());
        return 1;
    }
    std::printf("bem_mean_us %.3f\n", median_us(predictor.bem_mean, x));
    std::printf("forward_us %.3f\n", median_us(predictor.forward, x));
    return 0;
}
