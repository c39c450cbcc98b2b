// A minimal OpenFX host over the OFX Association's HostSupport library, to run kpcn.ofx
// headless (no OFX host installs on Debian). tests/plugins.rs builds and runs it:
//
//   OFX_PLUGIN_PATH=DIR ofx_host W H IMAGES [abort]
//
// IMAGES holds raw float RGBA images, rows bottom-up as OFX lays them out: Source.f32
// and, when present, Diffuse.f32, Albedo.f32, Normal.f32 and Depth.f32 (depth in R), each
// connected to its clip in the general context. Renders frame 0 into
// IMAGES/Output.f32 (RGBA) and prints "render: STATUS". With `abort`, the host's abort
// check says yes from the start.
// HostSupport's headers must come in this order.
// clang-format off
#include <ofxCore.h>
#include <ofxImageEffect.h>
#include <ofxPixels.h>
#include <ofxhBinary.h>
#include <ofxhPropertySuite.h>
#include <ofxhClip.h>
#include <ofxhParam.h>
#include <ofxhMemory.h>
#include <ofxhImageEffect.h>
#include <ofxhPluginAPICache.h>
#include <ofxhPluginCache.h>
#include <ofxhHost.h>
#include <ofxhImageEffectAPI.h>
// clang-format on

#include <cstdarg>
#include <cstdio>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace host {

using namespace OFX::Host;

int W = 0, H = 0;
bool aborting = false;
std::string folder;

std::vector<float> load(const std::string& name, int channels) {
    std::ifstream f(folder + "/" + name, std::ios::binary);
    if (!f) return {};
    std::vector<float> v(size_t(W) * H * channels);
    f.read(reinterpret_cast<char*>(v.data()), std::streamsize(v.size() * sizeof(float)));
    return f ? v : std::vector<float>{};
}

class Clip : public ImageEffect::ClipInstance {
public:
    Clip(ImageEffect::Instance* effect, ImageEffect::ClipDescriptor* desc)
        : ClipInstance(effect, *desc), name_(desc->getName()) {
        pixels_ = name_ == kOfxImageEffectOutputClipName ? std::vector<float>(size_t(W) * H * 4, 0.0f)
                                                         : load(name_ + ".f32", channels_);
    }
    const std::string& getUnmappedBitDepth() const override { return depth_; }
    const std::string& getUnmappedComponents() const override { return components_; }
    const std::string& getPremult() const override { return premult_; }
    double getAspectRatio() const override { return 1.0; }
    double getFrameRate() const override { return 25.0; }
    void getFrameRange(double& a, double& b) const override { a = b = 0; }
    const std::string& getFieldOrder() const override { return field_; }
    bool getConnected() const override { return !pixels_.empty(); }
    double getUnmappedFrameRate() const override { return 25.0; }
    void getUnmappedFrameRange(double& a, double& b) const override { a = b = 0; }
    bool getContinuousSamples() const override { return false; }
    OfxRectD getRegionOfDefinition(OfxTime) const override { return {0, 0, double(W), double(H)}; }
    ImageEffect::Image* getImage(OfxTime, const OfxRectD*) override {
        if (pixels_.empty()) return nullptr;
        OfxRectI all = {0, 0, W, H};
        return new ImageEffect::Image(*this, 1.0, 1.0, pixels_.data(), all, all, int(W * channels_ * sizeof(float)),
                                      kOfxImageFieldNone, name_);
    }
    const std::vector<float>& pixels() const { return pixels_; }

private:
    std::string name_, components_ = kOfxImageComponentRGBA, depth_ = kOfxBitDepthFloat, premult_ = kOfxImageUnPreMultiplied,
                                    field_ = kOfxImageFieldNone;
    int channels_ = 4;
    std::vector<float> pixels_;
};

class IntParam : public Param::IntegerInstance {
public:
    IntParam(Param::Descriptor& d, Param::SetInstance* set) : IntegerInstance(d, set) {
        value_ = d.getProperties().getIntProperty(kOfxParamPropDefault);
    }
    OfxStatus get(int& v) override { return v = value_, kOfxStatOK; }
    OfxStatus get(OfxTime, int& v) override { return v = value_, kOfxStatOK; }
    OfxStatus set(int v) override { return value_ = v, kOfxStatOK; }
    OfxStatus set(OfxTime, int v) override { return value_ = v, kOfxStatOK; }

private:
    int value_ = 0;
};

class Effect : public ImageEffect::Instance {
public:
    Effect(ImageEffect::ImageEffectPlugin* p, ImageEffect::Descriptor& d, const std::string& c)
        : Instance(p, d, c, false) {}
    const std::string& getDefaultOutputFielding() const override { return field_; }
    ImageEffect::ClipInstance* newClipInstance(ImageEffect::Instance*, ImageEffect::ClipDescriptor* d, int) override {
        return new Clip(this, d);
    }
    OfxStatus vmessage(const char* type, const char*, const char* format, va_list args) override {
        std::fprintf(stderr, "plugin %s: ", type);
        std::vfprintf(stderr, format, args);
        std::fprintf(stderr, "\n");
        return kOfxStatOK;
    }
    OfxStatus setPersistentMessage(const char* t, const char* i, const char* f, va_list a) override {
        return vmessage(t, i, f, a);
    }
    OfxStatus clearPersistentMessage() override { return kOfxStatOK; }
    void getProjectSize(double& x, double& y) const override { x = W, y = H; }
    void getProjectOffset(double& x, double& y) const override { x = y = 0; }
    void getProjectExtent(double& x, double& y) const override { x = W, y = H; }
    double getProjectPixelAspectRatio() const override { return 1.0; }
    double getEffectDuration() const override { return 1.0; }
    double getFrameRate() const override { return 25.0; }
    double getFrameRecursive() const override { return 0.0; }
    void getRenderScaleRecursive(double& x, double& y) const override { x = y = 1.0; }
    Param::Instance* newParam(const std::string&, Param::Descriptor& d) override {
        return d.getType() == kOfxParamTypeInteger ? new IntParam(d, this) : nullptr;
    }
    OfxStatus editBegin(const std::string&) override { return kOfxStatOK; }
    OfxStatus editEnd() override { return kOfxStatOK; }
    void progressStart(const std::string&, const std::string&) override {}
    void progressEnd() override {}
    bool progressUpdate(double) override { return true; }
    double timeLineGetTime() override { return 0; }
    void timeLineGotoTime(double) override {}
    void timeLineGetBounds(double& a, double& b) override { a = b = 0; }
    int abort() override {
        ++abort_checks;
        return aborting ? 1 : 0;
    }
    int abort_checks = 0;

private:
    std::string field_ = kOfxImageFieldNone;
};

class Host : public ImageEffect::Host {
public:
    Host() {
        _properties.setStringProperty(kOfxPropName, "org.kpcn.testhost");
        _properties.setStringProperty(kOfxPropLabel, "kpcn test host");
    }
    ImageEffect::Instance* newInstance(void*, ImageEffect::ImageEffectPlugin* p, ImageEffect::Descriptor& d,
                                       const std::string& c) override {
        return new Effect(p, d, c);
    }
    ImageEffect::Descriptor* makeDescriptor(ImageEffect::ImageEffectPlugin* p) override {
        return new ImageEffect::Descriptor(p);
    }
    ImageEffect::Descriptor* makeDescriptor(const ImageEffect::Descriptor& root, ImageEffect::ImageEffectPlugin* p) override {
        return new ImageEffect::Descriptor(root, p);
    }
    ImageEffect::Descriptor* makeDescriptor(const std::string& path, ImageEffect::ImageEffectPlugin* p) override {
        return new ImageEffect::Descriptor(path, p);
    }
    OfxStatus vmessage(const char*, const char*, const char* f, va_list a) override {
        std::vfprintf(stderr, f, a);
        return kOfxStatOK;
    }
    OfxStatus setPersistentMessage(const char* t, const char* i, const char* f, va_list a) override {
        return vmessage(t, i, f, a);
    }
    OfxStatus clearPersistentMessage() override { return kOfxStatOK; }
};

}  // namespace host

int main(int argc, char** argv) {
    using namespace OFX::Host;
    if (argc < 4) {
        std::fprintf(stderr, "usage: ofx_host W H IMAGES [abort]\n");
        return 2;
    }
    host::W = std::atoi(argv[1]);
    host::H = std::atoi(argv[2]);
    host::folder = argv[3];
    host::aborting = argc > 4 && std::string(argv[4]) == "abort";

    host::Host h;
    ImageEffect::PluginCache effects(h);
    effects.registerInCache(*PluginCache::getPluginCache());
    PluginCache::getPluginCache()->scanPluginFiles();
    ImageEffect::ImageEffectPlugin* plugin = effects.getPluginById("org.kpcn.denoise");
    if (!plugin) {
        std::fprintf(stderr, "org.kpcn.denoise not found on OFX_PLUGIN_PATH\n");
        return 1;
    }
    std::unique_ptr<ImageEffect::Instance> instance(plugin->createInstance(kOfxImageEffectContextGeneral, nullptr));
    if (!instance) {
        std::fprintf(stderr, "cannot create an instance in the general context\n");
        return 1;
    }
    OfxStatus s = instance->createInstanceAction();
    if (s != kOfxStatOK && s != kOfxStatReplyDefault) return std::fprintf(stderr, "createInstance: %d\n", s), 1;
    instance->getClipPreferences();
    OfxPointD scale = {1.0, 1.0};
    OfxRectI window = {0, 0, host::W, host::H};
    instance->beginRenderAction(0, 0, 1, false, scale, true, false);
    s = instance->renderAction(0, kOfxImageFieldNone, window, scale, true, false, false);
    instance->endRenderAction(0, 0, 1, false, scale, true, false);
    auto* effect = dynamic_cast<host::Effect*>(instance.get());
    std::printf("render: %d\nabort checks: %d\n", s, effect ? effect->abort_checks : -1);
    auto* out = dynamic_cast<host::Clip*>(instance->getClip(kOfxImageEffectOutputClipName));
    std::ofstream f(host::folder + "/Output.f32", std::ios::binary);
    f.write(reinterpret_cast<const char*>(out->pixels().data()), std::streamsize(out->pixels().size() * sizeof(float)));
    instance.reset();
    PluginCache::clearPluginCache();
    return s == kOfxStatOK ? 0 : 1;
}
