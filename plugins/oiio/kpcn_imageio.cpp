// kpcn.imageio.so: an OpenImageIO input plugin that denoises as it reads.
//
// Any OIIO program that opens `frame.exr.kpcn` gets the denoised beauty of `frame.exr` (R, G,
// B; float; the input's data window and metadata): `oiiotool shot.exr.kpcn -o den.exr` is a
// denoise step inside an oiiotool pipeline. Read-only; a thin shell over the C ABI
// (kpcn_denoise_file). Configuration hints (`ImageInput::open`'s config, or oiiotool
// `--iconfig kpcn:model FILE`): `kpcn:model` (a name or a .safetensors file; default `auto`,
// as `kpcn denoise`), `kpcn:threads`.
#include <kpcn.h>

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <atomic>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <unistd.h>

OIIO_PLUGIN_NAMESPACE_BEGIN

namespace {

const std::string suffix = ".kpcn";

bool has_suffix(const std::string& name) {
    return name.size() > suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0;
}

struct FreeDenoiser {
    void operator()(KpcnDenoiser* d) const { kpcn_denoiser_free(d); }
};

// Removes the temporary file however open() ends.
struct TempFile {
    std::string path;
    ~TempFile() { Filesystem::remove(path); }
};

}  // namespace

class KpcnInput final : public ImageInput {
public:
    const char* format_name() const override { return "kpcn"; }
    int supports(string_view feature) const override { return feature == "arbitrary_metadata"; }
    bool valid_file(const std::string& name) const override {
        return has_suffix(name) && Filesystem::is_regular(name.substr(0, name.size() - suffix.size()));
    }
    bool open(const std::string& name, ImageSpec& newspec) override { return open(name, newspec, ImageSpec()); }
    bool open(const std::string& name, ImageSpec& newspec, const ImageSpec& config) override;
    bool read_native_scanline(int subimage, int miplevel, int y, int z, void* data) override;
    bool close() override {
        pixels_.clear();
        pixels_.shrink_to_fit();
        return true;
    }

private:
    std::vector<float> pixels_;  // RGB rows of the data window
    bool fail(const std::string& what) {
        errorfmt("{}", what);
        return false;
    }
    // A failed open() of FILE.exr.kpcn: oiiotool checks that the path exists and, since
    // this one never does, reports "File does not exist" instead of the plugin's error
    // (iinfo shows it). So the library's message also goes to stderr, where either host's
    // user sees why.
    bool fail_open(const std::string& what) {
        std::fprintf(stderr, "kpcn ERROR: %s\n", what.c_str());
        return fail(what);
    }
};

bool KpcnInput::open(const std::string& name, ImageSpec& newspec, const ImageSpec& config) {
    if (!has_suffix(name)) return fail(name + ": the kpcn plugin reads FILE.exr.kpcn (the denoised FILE.exr)");
    const std::string source = name.substr(0, name.size() - suffix.size());

    KpcnOptions options;
    kpcn_options_init(&options);
    const std::string model = config.get_string_attribute("kpcn:model");
    if (model.size() > 12 && model.compare(model.size() - 12, 12, ".safetensors") == 0)
        options.model_path = model.c_str();
    else
        options.model_name = model.empty() ? "auto" : model.c_str();  // auto: as `kpcn denoise`
    options.threads = static_cast<uint32_t>(std::max(0, config.get_int_attribute("kpcn:threads", 0)));
    KpcnDenoiser* raw = nullptr;
    if (kpcn_denoiser_new(&options, &raw) != KPCN_OK) return fail_open(std::string("kpcn: ") + kpcn_last_error());
    std::unique_ptr<KpcnDenoiser, FreeDenoiser> denoiser(raw);

    // kpcn_denoise_file maps the renderer's channels and streams the frame in bands; its
    // denoised layer goes to a private temporary file that is read back and removed.
    static std::atomic<unsigned> counter{0};
    TempFile temp{Filesystem::temp_directory_path() + "/kpcn-imageio-" + std::to_string(getpid()) + "-" +
                  std::to_string(counter++) + ".exr"};
    KpcnFileOptions fo;
    kpcn_file_options_init(&fo);
    fo.separate = true;
    fo.layer = "denoised";
    if (kpcn_denoise_file(denoiser.get(), source.c_str(), temp.path.c_str(), &fo) != KPCN_OK)
        return fail_open(std::string("kpcn: ") + kpcn_last_error());

    auto in = ImageInput::open(temp.path);
    if (!in) return fail("kpcn: cannot read back the denoised layer: " + OIIO::geterror());
    const ImageSpec& den = in->spec();
    const int r = den.channelindex("denoised.R");
    if (r < 0 || den.channelindex("denoised.B") != r + 2) return fail("kpcn: the denoised layer is missing");
    pixels_.resize(size_t(den.width) * den.height * 3);
    if (!in->read_image(0, 0, r, r + 3, TypeDesc::FLOAT, pixels_.data()))
        return fail("kpcn: reading the denoised layer: " + in->geterror());
    in->close();

    m_spec = ImageSpec(den.width, den.height, 3, TypeDesc::FLOAT);
    m_spec.x = den.x;
    m_spec.y = den.y;
    m_spec.full_x = den.full_x;
    m_spec.full_y = den.full_y;
    m_spec.full_width = den.full_width;
    m_spec.full_height = den.full_height;
    m_spec.extra_attribs = den.extra_attribs;  // the input's metadata, plus kpcn:model
    m_spec.attribute("kpcn:source", source);
    newspec = m_spec;
    return true;
}

bool KpcnInput::read_native_scanline(int subimage, int miplevel, int y, int /*z*/, void* data) {
    lock_guard lock(*this);
    if (subimage != 0 || miplevel != 0) return fail("kpcn: one subimage, one MIP level");
    const int row = y - m_spec.y;
    if (row < 0 || row >= m_spec.height) return fail("kpcn: scanline out of range");
    const size_t n = size_t(m_spec.width) * 3;
    std::memcpy(data, pixels_.data() + size_t(row) * n, n * sizeof(float));
    return true;
}

OIIO_PLUGIN_NAMESPACE_END

OIIO_PLUGIN_EXPORTS_BEGIN
OIIO_EXPORT int kpcn_imageio_version = OIIO_PLUGIN_VERSION;
OIIO_EXPORT const char* kpcn_imageio_library_version() { return kpcn_version_string(); }
OIIO_EXPORT OIIO::ImageInput* kpcn_input_imageio_create() { return new OIIO::KpcnInput; }
OIIO_EXPORT const char* kpcn_input_extensions[] = {"kpcn", nullptr};
OIIO_PLUGIN_EXPORTS_END
