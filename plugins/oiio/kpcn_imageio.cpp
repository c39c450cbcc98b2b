// kpcn.imageio.so: an OpenImageIO input plugin that denoises as it reads.
//
// Any OIIO program that opens `frame.exr.kpcn` gets the denoised beauty of `frame.exr` (R, G,
// B; float; the input's data window and metadata): `oiiotool shot.exr.kpcn -o den.exr` is a
// denoise step inside an oiiotool pipeline. Read-only; a thin shell over the C ABI
// (kpcn_denoise_file). Configuration hints (`ImageInput::open`'s config, or oiiotool
// `--iconfig kpcn:model FILE`): `kpcn:model` (a name or a .safetensors file; default `auto`,
// as `kpcn denoise`), `kpcn:threads`.
//
// open() reads only the source's header, so `iinfo` and `oiiotool --info` denoise nothing;
// the first pixel read denoises, and the result is kept for the process (keyed by the
// source's path, size and modification time and the options), because OIIO opens a file
// several times in one command. KPCN_IMAGEIO_VERBOSE=1 prints each denoise to stderr.
#include <kpcn.h>

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <tuple>
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

// One denoised frame: RGB rows of the source's data window.
struct Denoised {
    std::vector<float> pixels;
};

// What identifies a denoise: the source file as it is now, and the options.
struct Key {
    std::string source;
    uintmax_t size = 0;
    std::time_t mtime = 0;
    std::string model;
    int threads = 0;
    bool operator==(const Key& o) const {
        return std::tie(source, size, mtime, model, threads) == std::tie(o.source, o.size, o.mtime, o.model, o.threads);
    }
};

// The process's last few denoised frames (a pipeline reads a handful of inputs; a sequence
// moves on), so that the several opens of one oiiotool command denoise once.
class Cache {
public:
    std::shared_ptr<const Denoised> find(const Key& key) {
        std::lock_guard<std::mutex> lock(mutex_);
        for (auto& e : entries_)
            if (e.first == key) return e.second;
        return nullptr;
    }
    void insert(const Key& key, std::shared_ptr<const Denoised> d) {
        std::lock_guard<std::mutex> lock(mutex_);
        entries_.emplace_back(key, std::move(d));
        while (entries_.size() > 4) entries_.pop_front();
    }

private:
    std::mutex mutex_;
    std::deque<std::pair<Key, std::shared_ptr<const Denoised>>> entries_;
};

Cache& cache() {
    static Cache c;
    return c;
}

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
        pixels_.reset();
        return true;
    }

private:
    Key key_;
    std::shared_ptr<const Denoised> pixels_;  // null until the first read
    bool denoise();
    bool fail(const std::string& what) {
        errorfmt("{}", what);
        return false;
    }
    // A failed open() of FILE.exr.kpcn: oiiotool checks that the path exists and, since
    // this one never does, reports "File does not exist" instead of the plugin's error
    // (iinfo shows it). So the message also goes to stderr. (Errors of the denoise itself
    // come at the first read, which oiiotool reports with the plugin's own message.)
    bool fail_open(const std::string& what) {
        std::fprintf(stderr, "kpcn ERROR: %s\n", what.c_str());
        return fail(what);
    }
};

bool KpcnInput::open(const std::string& name, ImageSpec& newspec, const ImageSpec& config) {
    if (!has_suffix(name)) return fail(name + ": the kpcn plugin reads FILE.exr.kpcn (the denoised FILE.exr)");
    const std::string source = name.substr(0, name.size() - suffix.size());
    if (!Filesystem::is_regular(source)) return fail_open("kpcn: " + source + ": no such file");
    key_ = Key{source, Filesystem::file_size(source), Filesystem::last_write_time(source),
               config.get_string_attribute("kpcn:model"), std::max(0, config.get_int_attribute("kpcn:threads", 0))};
    pixels_ = cache().find(key_);

    // The header alone: the pixels are denoised on the first read.
    auto in = ImageInput::open(source);
    if (!in) return fail_open("kpcn: " + source + ": " + OIIO::geterror());
    const ImageSpec& src = in->spec();
    m_spec = ImageSpec(src.width, src.height, 3, TypeDesc::FLOAT);
    m_spec.x = src.x;
    m_spec.y = src.y;
    m_spec.full_x = src.full_x;
    m_spec.full_y = src.full_y;
    m_spec.full_width = src.full_width;
    m_spec.full_height = src.full_height;
    m_spec.extra_attribs = src.extra_attribs;  // the input's metadata
    m_spec.erase_attribute("compression");
    m_spec.attribute("kpcn:source", source);
    in->close();
    newspec = m_spec;
    return true;
}

bool KpcnInput::denoise() {
    if (pixels_) return true;
    if ((pixels_ = cache().find(key_))) return true;
    const auto start = std::chrono::steady_clock::now();
    KpcnOptions options;
    kpcn_options_init(&options);
    const std::string& model = key_.model;
    if (model.size() > 12 && model.compare(model.size() - 12, 12, ".safetensors") == 0)
        options.model_path = model.c_str();
    else
        options.model_name = model.empty() ? "auto" : model.c_str();  // auto: as `kpcn denoise`
    options.threads = static_cast<uint32_t>(key_.threads);
    KpcnDenoiser* raw = nullptr;
    if (kpcn_denoiser_new(&options, &raw) != KPCN_OK) return fail(std::string("kpcn: ") + kpcn_last_error());
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
    if (kpcn_denoise_file(denoiser.get(), key_.source.c_str(), temp.path.c_str(), &fo) != KPCN_OK)
        return fail(std::string("kpcn: ") + kpcn_last_error());

    auto in = ImageInput::open(temp.path);
    if (!in) return fail("kpcn: cannot read back the denoised layer: " + OIIO::geterror());
    const ImageSpec& den = in->spec();
    const int r = den.channelindex("denoised.R");
    if (r < 0 || den.channelindex("denoised.B") != r + 2) return fail("kpcn: the denoised layer is missing");
    if (den.width != m_spec.width || den.height != m_spec.height)
        return fail("kpcn: " + key_.source + " changed while it was read");
    auto d = std::make_shared<Denoised>();
    d->pixels.resize(size_t(den.width) * den.height * 3);
    if (!in->read_image(0, 0, r, r + 3, TypeDesc::FLOAT, d->pixels.data()))
        return fail("kpcn: reading the denoised layer: " + in->geterror());
    in->close();
    pixels_ = d;
    cache().insert(key_, d);
    if (const char* v = std::getenv("KPCN_IMAGEIO_VERBOSE"); v && *v && std::strcmp(v, "0") != 0) {
        const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        std::fprintf(stderr, "kpcn: denoised %s (%.1f s)\n", key_.source.c_str(), s);
    }
    return true;
}

bool KpcnInput::read_native_scanline(int subimage, int miplevel, int y, int /*z*/, void* data) {
    lock_guard lock(*this);
    if (subimage != 0 || miplevel != 0) return fail("kpcn: one subimage, one MIP level");
    const int row = y - m_spec.y;
    if (row < 0 || row >= m_spec.height) return fail("kpcn: scanline out of range");
    if (!denoise()) return false;
    const size_t n = size_t(m_spec.width) * 3;
    std::memcpy(data, pixels_->pixels.data() + size_t(row) * n, n * sizeof(float));
    return true;
}

OIIO_PLUGIN_NAMESPACE_END

OIIO_PLUGIN_EXPORTS_BEGIN
OIIO_EXPORT int kpcn_imageio_version = OIIO_PLUGIN_VERSION;
OIIO_EXPORT const char* kpcn_imageio_library_version() { return kpcn_version_string(); }
OIIO_EXPORT OIIO::ImageInput* kpcn_input_imageio_create() { return new OIIO::KpcnInput; }
OIIO_EXPORT const char* kpcn_input_extensions[] = {"kpcn", nullptr};
OIIO_PLUGIN_EXPORTS_END
