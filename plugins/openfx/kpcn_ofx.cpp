// kpcn.ofx: an OpenFX image-effect plugin on the kpcn C ABI, for compositors (Nuke, Natron,
// Resolve, Fusion, Vegas). Identifier org.kpcn.denoise.
//
// Contexts: filter (Source → Output) and general, which adds optional clips Diffuse, Albedo,
// Normal and Depth. Without Diffuse, the whole Source is filtered as diffuse light; without
// Albedo, Normal or Depth, neutral values (white, zero) stand in. 32-bit float RGB/RGBA
// images (Depth may be Alpha); rows are bottom-up as OFX lays them out (negative row
// strides in kpcn). Parameters: Threads and Max Memory (MB). The host's abort check cancels
// between tiles. Output alpha is the Source's (or 1).
#include <kpcn.h>

#include <ofxCore.h>
#include <ofxImageEffect.h>
#include <ofxMessage.h>
#include <ofxParam.h>
#include <ofxProperty.h>

#include <cstring>
#include <memory>
#include <string>
#include <vector>

namespace {

OfxHost* host = nullptr;
OfxPropertySuiteV1* props = nullptr;
OfxImageEffectSuiteV1* effects = nullptr;
OfxParameterSuiteV1* params = nullptr;
OfxMessageSuiteV1* messages = nullptr;  // optional

const char* const kClipDiffuse = "Diffuse";
const char* const kClipAlbedo = "Albedo";
const char* const kClipNormal = "Normal";
const char* const kClipDepth = "Depth";
const char* const kParamThreads = "threads";
const char* const kParamMemory = "maxMemory";

OfxStatus fail(OfxImageEffectHandle instance, const std::string& what) {
    if (messages && instance) messages->message(instance, kOfxMessageError, "", "kpcn: %s", what.c_str());
    return kOfxStatFailed;
}

// An image fetched from a clip, released on scope exit.
struct ClipImage {
    OfxPropertySetHandle handle = nullptr;
    void* data = nullptr;
    OfxRectI bounds{};
    int row_bytes = 0;
    int channels = 0;
    std::string depth;

    ClipImage() = default;
    ClipImage(const ClipImage&) = delete;
    ClipImage& operator=(const ClipImage&) = delete;
    ~ClipImage() {
        if (handle) effects->clipReleaseImage(handle);
    }

    // False when the clip is absent, unconnected or gives no image.
    bool fetch(OfxImageEffectHandle instance, const char* clip_name, OfxTime time) {
        OfxImageClipHandle clip = nullptr;
        OfxPropertySetHandle clip_props = nullptr;
        if (effects->clipGetHandle(instance, clip_name, &clip, &clip_props) != kOfxStatOK) return false;
        int connected = 0;
        props->propGetInt(clip_props, kOfxImageClipPropConnected, 0, &connected);
        if (!connected || effects->clipGetImage(clip, time, nullptr, &handle) != kOfxStatOK) return false;
        props->propGetPointer(handle, kOfxImagePropData, 0, &data);
        props->propGetIntN(handle, kOfxImagePropBounds, 4, &bounds.x1);
        props->propGetInt(handle, kOfxImagePropRowBytes, 0, &row_bytes);
        char* s = nullptr;
        props->propGetString(handle, kOfxImageEffectPropComponents, 0, &s);
        const std::string comps = s ? s : "";
        channels = comps == kOfxImageComponentRGBA ? 4 : comps == kOfxImageComponentRGB ? 3 : comps == kOfxImageComponentAlpha ? 1 : 0;
        props->propGetString(handle, kOfxImageEffectPropPixelDepth, 0, &s);
        depth = s ? s : "";
        return data != nullptr;
    }

    int width() const { return bounds.x2 - bounds.x1; }
    int height() const { return bounds.y2 - bounds.y1; }

    // The top row and a negative row stride: OFX rows run bottom-up.
    void* top() const { return static_cast<char*>(data) + std::ptrdiff_t(height() - 1) * row_bytes; }

    int32_t format() const {
        return channels == 4 ? KPCN_FORMAT_FLOAT4 : channels == 3 ? KPCN_FORMAT_FLOAT3 : KPCN_FORMAT_FLOAT;
    }
};

struct FreeDenoiser {
    void operator()(KpcnDenoiser* d) const { kpcn_denoiser_free(d); }
};

bool keep_going(void* instance, double) { return !effects->abort(static_cast<OfxImageEffectHandle>(instance)); }

OfxStatus describe(OfxImageEffectHandle effect) {
    OfxPropertySetHandle p;
    effects->getPropertySet(effect, &p);
    props->propSetString(p, kOfxPropLabel, 0, "kpcn Denoise");
    props->propSetString(p, kOfxImageEffectPluginPropGrouping, 0, "Filter");
    props->propSetString(p, kOfxImageEffectPropSupportedContexts, 0, kOfxImageEffectContextFilter);
    props->propSetString(p, kOfxImageEffectPropSupportedContexts, 1, kOfxImageEffectContextGeneral);
    props->propSetString(p, kOfxImageEffectPropSupportedPixelDepths, 0, kOfxBitDepthFloat);
    // The network sees up to ~50 px around each pixel: it needs whole frames, not tiles.
    props->propSetInt(p, kOfxImageEffectPropSupportsTiles, 0, 0);
    props->propSetInt(p, kOfxImageEffectPropSupportsMultiResolution, 0, 0);
    props->propSetString(p, kOfxImageEffectPluginRenderThreadSafety, 0, kOfxImageEffectRenderInstanceSafe);
    // kpcn runs its own threads.
    props->propSetInt(p, kOfxImageEffectPluginPropHostFrameThreading, 0, 0);
    return kOfxStatOK;
}

void define_clip(OfxImageEffectHandle effect, const char* name, bool optional, bool alpha) {
    OfxPropertySetHandle p;
    effects->clipDefine(effect, name, &p);
    props->propSetString(p, kOfxImageEffectPropSupportedComponents, 0, kOfxImageComponentRGBA);
    props->propSetString(p, kOfxImageEffectPropSupportedComponents, 1, kOfxImageComponentRGB);
    if (alpha) props->propSetString(p, kOfxImageEffectPropSupportedComponents, 2, kOfxImageComponentAlpha);
    props->propSetInt(p, kOfxImageClipPropOptional, 0, optional ? 1 : 0);
    props->propSetInt(p, kOfxImageEffectPropSupportsTiles, 0, 0);
}

void define_int(OfxParamSetHandle set, const char* name, const char* label, int value, int min, int max,
                const char* hint) {
    OfxPropertySetHandle p;
    params->paramDefine(set, kOfxParamTypeInteger, name, &p);
    props->propSetString(p, kOfxPropLabel, 0, label);
    props->propSetString(p, kOfxParamPropHint, 0, hint);
    props->propSetInt(p, kOfxParamPropDefault, 0, value);
    props->propSetInt(p, kOfxParamPropMin, 0, min);
    props->propSetInt(p, kOfxParamPropMax, 0, max);
}

OfxStatus describe_in_context(OfxImageEffectHandle effect, OfxPropertySetHandle in_args) {
    char* context = nullptr;
    props->propGetString(in_args, kOfxImageEffectPropContext, 0, &context);
    define_clip(effect, kOfxImageEffectSimpleSourceClipName, false, false);
    define_clip(effect, kOfxImageEffectOutputClipName, false, false);
    if (context && std::strcmp(context, kOfxImageEffectContextGeneral) == 0) {
        define_clip(effect, kClipDiffuse, true, false);
        define_clip(effect, kClipAlbedo, true, false);
        define_clip(effect, kClipNormal, true, false);
        define_clip(effect, kClipDepth, true, true);
    }
    OfxParamSetHandle set;
    effects->getParamSet(effect, &set);
    define_int(set, kParamThreads, "Threads", 0, 0, 1024, "Worker threads kpcn uses; 0 = every core");
    define_int(set, kParamMemory, "Max Memory (MB)", 512, 16, 65536, "Working-memory budget of one tile");
    return kOfxStatOK;
}

int int_param(OfxImageEffectHandle instance, const char* name, OfxTime time) {
    OfxParamSetHandle set;
    OfxParamHandle param;
    int v = 0;
    effects->getParamSet(instance, &set);
    if (params->paramGetHandle(set, name, &param, nullptr) == kOfxStatOK) params->paramGetValueAtTime(param, time, &v);
    return v;
}

OfxStatus render(OfxImageEffectHandle instance, OfxPropertySetHandle in_args) {
    OfxTime time = 0;
    props->propGetDouble(in_args, kOfxPropTime, 0, &time);
    ClipImage src, out, diffuse, albedo, normal, depth;
    if (!src.fetch(instance, kOfxImageEffectSimpleSourceClipName, time)) return fail(instance, "no Source image");
    if (!out.fetch(instance, kOfxImageEffectOutputClipName, time)) return fail(instance, "no Output image");
    const int w = out.width(), h = out.height();
    auto check = [&](const ClipImage& im, const char* name) -> std::string {
        if (im.depth != kOfxBitDepthFloat) return std::string(name) + " is not 32-bit float";
        if (im.width() != w || im.height() != h || im.bounds.x1 != out.bounds.x1 || im.bounds.y1 != out.bounds.y1)
            return std::string(name) + "'s bounds differ from Output's: give every clip the same format";
        return "";
    };
    for (auto [im, name] : {std::pair{&src, "Source"}, std::pair{&out, "Output"}})
        if (auto e = check(*im, name); !e.empty()) return fail(instance, e);

    KpcnOptions o;
    kpcn_options_init(&o);
    // As `kpcn denoise`: the host hands no variance clips, so this is the `spatial` model,
    // trained on the spatial estimates kpcn makes for them.
    o.model_name = "auto";
    o.threads = static_cast<uint32_t>(int_param(instance, kParamThreads, time));
    o.max_memory_mb = static_cast<uint32_t>(int_param(instance, kParamMemory, time));
    KpcnDenoiser* raw = nullptr;
    if (kpcn_denoiser_new(&o, &raw) != KPCN_OK) return fail(instance, kpcn_last_error());
    std::unique_ptr<KpcnDenoiser, FreeDenoiser> d(raw);

    // Neutral stand-ins for unconnected optional clips.
    const size_t n = size_t(w) * h;
    std::vector<float> white(n * 3, 1.0f), zeros(n * 3, 0.0f);
    auto set = [&](const char* name, const ClipImage& im) {
        return kpcn_set_image(d.get(), name, im.top(), im.format(), w, h, 0, -std::ptrdiff_t(im.row_bytes));
    };
    auto set_const = [&](const char* name, std::vector<float>& v, int32_t format) {
        return kpcn_set_image(d.get(), name, v.data(), format, w, h, 0, 0);
    };
    KpcnStatus s = set("color", src);
    const struct {
        ClipImage* image;
        const char* clip;
        const char* input;
    } optional[] = {{&diffuse, kClipDiffuse, "diffuse"}, {&albedo, kClipAlbedo, "albedo"},
                    {&normal, kClipNormal, "normal"}, {&depth, kClipDepth, "depth"}};
    for (const auto& c : optional) {
        if (s != KPCN_OK) break;
        if (c.image->fetch(instance, c.clip, time)) {
            if (auto e = check(*c.image, c.clip); !e.empty()) return fail(instance, e);
            s = set(c.input, *c.image);
        } else if (c.image == &diffuse) {
            s = set("diffuse", src);  // everything filtered as diffuse; specular = 0
        } else if (c.image == &albedo) {
            s = set_const("albedo", white, KPCN_FORMAT_FLOAT3);
        } else {
            s = set_const(c.input, zeros, c.image == &depth ? KPCN_FORMAT_FLOAT : KPCN_FORMAT_FLOAT3);
        }
    }
    if (s == KPCN_OK) s = set("output", out);
    if (s == KPCN_OK) s = kpcn_set_progress_callback(d.get(), keep_going, instance);
    if (s == KPCN_OK) s = kpcn_execute(d.get());
    if (s == KPCN_ERROR_CANCELLED) return kOfxStatOK;  // the host aborted: it discards the frame
    if (s != KPCN_OK) return fail(instance, kpcn_last_error());
    if (out.channels == 4) {
        for (int y = 0; y < h; ++y) {
            float* o4 = reinterpret_cast<float*>(static_cast<char*>(out.data) + std::ptrdiff_t(y) * out.row_bytes);
            const float* s4 = reinterpret_cast<const float*>(static_cast<char*>(src.data) + std::ptrdiff_t(y) * src.row_bytes);
            for (int x = 0; x < w; ++x) o4[4 * x + 3] = src.channels == 4 ? s4[4 * x + 3] : 1.0f;
        }
    }
    return kOfxStatOK;
}

template <class T>
bool fetch_suite(T*& suite, const char* name, int version) {
    suite = static_cast<T*>(const_cast<void*>(host->fetchSuite(host->host, name, version)));
    return suite != nullptr;
}

OfxStatus main_entry(const char* action, const void* handle, OfxPropertySetHandle in_args, OfxPropertySetHandle) {
    auto effect = static_cast<OfxImageEffectHandle>(const_cast<void*>(handle));
    try {
        if (std::strcmp(action, kOfxActionLoad) == 0) {
            if (!host) return kOfxStatErrMissingHostFeature;
            fetch_suite(messages, kOfxMessageSuite, 1);
            return fetch_suite(props, kOfxPropertySuite, 1) && fetch_suite(effects, kOfxImageEffectSuite, 1) &&
                           fetch_suite(params, kOfxParameterSuite, 1)
                       ? kOfxStatOK
                       : kOfxStatErrMissingHostFeature;
        }
        if (std::strcmp(action, kOfxActionDescribe) == 0) return describe(effect);
        if (std::strcmp(action, kOfxImageEffectActionDescribeInContext) == 0)
            return describe_in_context(effect, in_args);
        if (std::strcmp(action, kOfxImageEffectActionRender) == 0) return render(effect, in_args);
    } catch (const std::exception& e) {
        // Nothing may unwind into the host.
        return fail(effect, e.what());
    } catch (...) {
        return kOfxStatFailed;
    }
    return kOfxStatReplyDefault;
}

void set_host(OfxHost* h) { host = h; }

OfxPlugin plugin = {kOfxImageEffectPluginApi, 1, "org.kpcn.denoise", 0, 1, set_host, main_entry};

}  // namespace

// The two entry points every OFX binary exports (the rest is hidden: -fvisibility=hidden).
extern "C" __attribute__((visibility("default"))) int OfxGetNumberOfPlugins(void) { return 1; }
extern "C" __attribute__((visibility("default"))) OfxPlugin* OfxGetPlugin(int nth) {
    return nth == 0 ? &plugin : nullptr;
}
