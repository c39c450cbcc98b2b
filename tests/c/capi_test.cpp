// The C API from C++17 (tests/capi.rs builds and runs this): a small RAII wrapper, errors as
// exceptions, and the file call.
//
//   capi_test_cpp INPUT.exr OUTPUT.exr
//
// Writes only the denoised layers (`separate`, `aovs`) and prints "ok".
#include <kpcn.h>

#include <cstdio>
#include <memory>
#include <stdexcept>
#include <string>

namespace {

void check(KpcnStatus s) {
    if (s != KPCN_OK) throw std::runtime_error(std::string(kpcn_status_string(s)) + ": " + kpcn_last_error());
}

struct Free {
    void operator()(KpcnDenoiser* d) const { kpcn_denoiser_free(d); }
};
using Denoiser = std::unique_ptr<KpcnDenoiser, Free>;

Denoiser make_denoiser(unsigned threads) {
    KpcnOptions o;
    check(kpcn_options_init(&o));
    o.threads = threads;
    KpcnDenoiser* d = nullptr;
    check(kpcn_denoiser_new(&o, &d));
    return Denoiser(d);
}

}  // namespace

int main(int argc, char** argv) {
    if (argc != 3) {
        std::fprintf(stderr, "usage: capi_test_cpp INPUT.exr OUTPUT.exr\n");
        return 2;
    }
    try {
        Denoiser d = make_denoiser(2);
        // A failure surfaces as an exception with the library's message.
        try {
            check(kpcn_execute(d.get()));
            std::fprintf(stderr, "execute without images succeeded\n");
            return 1;
        } catch (const std::runtime_error& e) {
            if (std::string(e.what()).find("no input") == std::string::npos) throw;
        }
        KpcnFileOptions fo;
        check(kpcn_file_options_init(&fo));
        fo.aovs = true;
        fo.separate = true;
        fo.layout = KPCN_LAYOUT_NATIVE;
        check(kpcn_denoise_file(d.get(), argv[1], argv[2], &fo));
    } catch (const std::exception& e) {
        std::fprintf(stderr, "error: %s\n", e.what());
        return 1;
    }
    std::printf("ok\n");
    return 0;
}
