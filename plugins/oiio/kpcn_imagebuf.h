// kpcn_imagebuf.h: denoise OpenImageIO ImageBufs with kpcn, for C++ tools that hold their
// frames in ImageBufs. Header-only, on the C ABI; link with
// `pkg-config --cflags --libs kpcn OpenImageIO`.
//
//   kpcn::ImageBufInputs in;
//   in.color = &beauty; in.diffuse = &diffuse; in.albedo = &albedo; in.normal = &normal; in.depth = &depth;
//   OIIO::ImageBuf out;
//   std::string error;
//   if (!kpcn::denoise(in, out, error)) std::cerr << error << "\n";
//
// Each input is read in place when it is float with local pixels (any channel count ≥ the
// one needed, any strides), else through a float copy. `out` becomes a 3-channel float
// image over the inputs' data window.
#ifndef KPCN_IMAGEBUF_H
#define KPCN_IMAGEBUF_H

#include <kpcn.h>

#include <OpenImageIO/imagebuf.h>

#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace kpcn {

/// The images kpcn reads, by role. `color` or `specular` may be absent (derived from the
/// other two); variances are estimated, as for files without them.
struct ImageBufInputs {
    const OIIO::ImageBuf* color = nullptr;
    const OIIO::ImageBuf* diffuse = nullptr;
    const OIIO::ImageBuf* specular = nullptr;
    const OIIO::ImageBuf* albedo = nullptr;
    const OIIO::ImageBuf* normal = nullptr;
    const OIIO::ImageBuf* depth = nullptr;
};

/// Denoises `in` into `out` (the beauty). `options` NULL = the defaults with model `auto`
/// (as `kpcn denoise`: `spatial` for buffers without variances, which ImageBufs of a
/// renderer's passes usually are), every core. On failure returns false and says why in
/// `error`.
inline bool denoise(const ImageBufInputs& in, OIIO::ImageBuf& out, std::string& error,
                    const KpcnOptions* options = nullptr) {
    struct Free {
        void operator()(KpcnDenoiser* d) const { kpcn_denoiser_free(d); }
    };
    KpcnOptions defaults;
    if (!options) {
        kpcn_options_init(&defaults);
        defaults.model_name = "auto";
        options = &defaults;
    }
    KpcnDenoiser* raw = nullptr;
    if (kpcn_denoiser_new(options, &raw) != KPCN_OK) return error = kpcn_last_error(), false;
    std::unique_ptr<KpcnDenoiser, Free> d(raw);

    const OIIO::ImageBuf* any = in.color ? in.color : in.diffuse;
    if (!any) return error = "kpcn: give at least color or diffuse", false;
    const OIIO::ROI roi = any->roi();
    std::vector<std::unique_ptr<OIIO::ImageBuf>> copies;  // float copies, alive until execute returns
    const std::pair<const char*, const OIIO::ImageBuf*> images[] = {
        {"color", in.color},   {"diffuse", in.diffuse}, {"specular", in.specular},
        {"albedo", in.albedo}, {"normal", in.normal},   {"depth", in.depth}};
    for (const auto& [name, buf] : images) {
        if (!buf) continue;
        const OIIO::ImageBuf* b = buf;
        if (b->spec().format != OIIO::TypeDesc::FLOAT || !b->localpixels()) {
            copies.push_back(std::make_unique<OIIO::ImageBuf>());
            if (!copies.back()->copy(*b, OIIO::TypeDesc::FLOAT)) return error = "kpcn: " + copies.back()->geterror(), false;
            b = copies.back().get();
        }
        if (b->roi().width() != roi.width() || b->roi().height() != roi.height())
            return error = std::string("kpcn: image `") + name + "` differs in size from the others", false;
        const int channels = b->nchannels();
        const int32_t format = channels >= 4 ? KPCN_FORMAT_FLOAT4 : channels == 3 ? KPCN_FORMAT_FLOAT3 : KPCN_FORMAT_FLOAT;
        void* top = const_cast<void*>(b->pixeladdr(b->xbegin(), b->ybegin()));
        if (kpcn_set_image(d.get(), name, top, format, size_t(roi.width()), size_t(roi.height()), b->pixel_stride(),
                           b->scanline_stride()) != KPCN_OK)
            return error = kpcn_last_error(), false;
    }
    OIIO::ImageSpec spec(roi.width(), roi.height(), 3, OIIO::TypeDesc::FLOAT);
    spec.x = roi.xbegin;
    spec.y = roi.ybegin;
    spec.full_x = any->spec().full_x;
    spec.full_y = any->spec().full_y;
    spec.full_width = any->spec().full_width;
    spec.full_height = any->spec().full_height;
    out.reset(spec);
    if (kpcn_set_image(d.get(), "output", out.localpixels(), KPCN_FORMAT_FLOAT3, size_t(roi.width()),
                       size_t(roi.height()), out.pixel_stride(), out.scanline_stride()) != KPCN_OK ||
        kpcn_execute(d.get()) != KPCN_OK)
        return error = kpcn_last_error(), false;
    return true;
}

}  // namespace kpcn

#endif  // KPCN_IMAGEBUF_H
