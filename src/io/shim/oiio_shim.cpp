// kpcn's thin C shim over OpenImageIO 2.4. See oiio_shim.h for the contract:
// every exported function catches everything and reports through a status.
#include "oiio_shim.h"

#include <OpenImageIO/imageio.h>
#include <OpenImageIO/oiioversion.h>

#include <cstring>
#include <exception>
#include <new>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

using namespace OIIO;

namespace {

thread_local std::string g_last_error;

int fail(std::string msg) {
    if (msg.empty())
        msg = "unknown OpenImageIO error";
    // OIIO error texts often end with a newline; keep ours on one line.
    while (!msg.empty() && (msg.back() == '\n' || msg.back() == ' '))
        msg.pop_back();
    g_last_error = std::move(msg);
    return -1;
}

int ok() {
    g_last_error.clear();
    return 0;
}

// Runs `f`, turning any exception into a failed status; running out of memory gets its
// own status, so that it is never reported as a corrupt file.
template <typename F> int guarded(F&& f) {
    try {
        return f();
    } catch (const std::bad_alloc&) {
        fail("out of memory");
        return KPCN_SHIM_OUT_OF_MEMORY;
    } catch (const std::exception& e) {
        return fail(std::string("internal error: ") + e.what());
    } catch (...) {
        return fail("internal error: unknown C++ exception");
    }
}

int format_code(TypeDesc t) {
    if (t == TypeDesc::HALF)
        return KPCN_FORMAT_HALF;
    if (t == TypeDesc::FLOAT)
        return KPCN_FORMAT_FLOAT;
    if (t == TypeDesc::UINT)
        return KPCN_FORMAT_UINT;
    return KPCN_FORMAT_OTHER;
}

bool is_single_string(TypeDesc t) {
    return t.basetype == TypeDesc::STRING && t.arraylen == 0 && t.aggregate == TypeDesc::SCALAR;
}

}  // namespace

struct kpcn_input {
    std::unique_ptr<ImageInput> in;
    std::vector<ImageSpec> specs;
    std::vector<std::vector<std::string>> attr_texts;  // per subimage, per attribute
    std::vector<std::string> names;                   // per subimage
};

struct kpcn_output {
    std::unique_ptr<ImageOutput> out;
    std::vector<ImageSpec> specs;
    std::string path;
    int part = 0;
};

extern "C" {

const char* kpcn_oiio_last_error(void) { return g_last_error.c_str(); }

int kpcn_oiio_version(void) { return OIIO_VERSION; }

int kpcn_oiio_set_exr_threads(int n) {
    return guarded([&] { return OIIO::attribute("exr_threads", n) ? ok() : fail("exr_threads refused"); });
}

int kpcn_input_open(const char* path, int openexr_core, kpcn_input** out) {
    return guarded([&]() {
        *out = nullptr;
        std::unique_ptr<ImageInput> in;
        if (openexr_core) {
            // OpenImageIO picks its EXR reader from a global attribute when the reader is
            // made: set for this open only (one at a time), and put back even on a throw.
            static std::mutex core_mutex;
            std::lock_guard<std::mutex> lock(core_mutex);
            int before = 0;
            OIIO::getattribute("openexr:core", before);
            struct Restore {
                int before;
                ~Restore() { OIIO::attribute("openexr:core", before); }
            } restore{before};
            OIIO::attribute("openexr:core", 1);
            in = ImageInput::open(path);
            // Its reads decode their chunks on the calling thread, like the classic
            // reader's with `exr_threads` at -1: the caller spreads reads over handles.
            if (in)
                in->threads(1);
        } else {
            in = ImageInput::open(path);
        }
        if (!in)
            return fail(OIIO::geterror());
        auto h = std::make_unique<kpcn_input>();
        for (int s = 0; in->seek_subimage(s, 0); ++s) {
            ImageSpec spec = in->spec(s, 0);
            std::vector<std::string> texts;
            texts.reserve(spec.extra_attribs.size());
            for (const ParamValue& p : spec.extra_attribs)
                texts.push_back(is_single_string(p.type()) ? std::string(p.get_ustring().string())
                                                           : p.get_string(4096));
            std::string name = spec.get_string_attribute("oiio:subimagename");
            if (name.empty())
                name = spec.get_string_attribute("name");
            h->names.push_back(name);
            h->attr_texts.push_back(std::move(texts));
            h->specs.push_back(std::move(spec));
        }
        // The seek past the last subimage that ends the loop is no error, but some readers
        // (TIFF) record one: dropped once at least one subimage was read.
        if (h->specs.empty())
            return fail(in->has_error() ? in->geterror() : std::string("the file holds no image"));
        (void)in->geterror();
        h->in = std::move(in);
        *out = h.release();
        return ok();
    });
}

void kpcn_input_close(kpcn_input* in) {
    try {
        if (in && in->in)
            in->in->close();
    } catch (...) {
    }
    delete in;
}

const char* kpcn_input_format_name(const kpcn_input* in) { return in->in->format_name(); }

int kpcn_input_subimages(const kpcn_input* in) { return int(in->specs.size()); }

int kpcn_input_subimage_info(const kpcn_input* in, int s, kpcn_subimage_info* info) {
    if (s < 0 || s >= int(in->specs.size()))
        return fail("subimage index out of range");
    const ImageSpec& sp = in->specs[s];
    info->x = sp.x;
    info->y = sp.y;
    info->width = sp.width;
    info->height = sp.height;
    info->full_x = sp.full_x;
    info->full_y = sp.full_y;
    info->full_width = sp.full_width;
    info->full_height = sp.full_height;
    info->nchannels = sp.nchannels;
    info->tile_width = sp.tile_width;
    info->tile_height = sp.tile_height;
    info->deep = sp.deep ? 1 : 0;
    return ok();
}

const char* kpcn_input_subimage_name(const kpcn_input* in, int s) {
    return in->names[s].c_str();
}

const char* kpcn_input_channel_name(const kpcn_input* in, int s, int c) {
    return in->specs[s].channelnames[c].c_str();
}

int kpcn_input_channel_format(const kpcn_input* in, int s, int c) {
    return format_code(in->specs[s].channelformat(c));
}

int kpcn_input_attribute_count(const kpcn_input* in, int s) {
    return int(in->specs[s].extra_attribs.size());
}

int kpcn_input_attribute(const kpcn_input* in, int s, int i, kpcn_attribute* a) {
    if (s < 0 || s >= int(in->specs.size()) || i < 0 || i >= int(in->specs[s].extra_attribs.size()))
        return fail("attribute index out of range");
    const ParamValue& p = in->specs[s].extra_attribs[i];
    a->name = p.name().c_str();
    a->type = p.type().c_str();
    a->text = in->attr_texts[s][i].c_str();
    a->is_string = is_single_string(p.type()) ? 1 : 0;
    bool has_strings = p.type().basetype == TypeDesc::STRING || p.type().basetype == TypeDesc::PTR;
    a->data = has_strings ? nullptr : p.data();
    a->size = has_strings ? 0 : size_t(p.datasize());
    return ok();
}

int kpcn_input_read_rows(kpcn_input* in, int s, int ybegin, int yend, int chbegin, int chend,
                         float* data) {
    return guarded([&]() {
        if (s < 0 || s >= int(in->specs.size()))
            return fail("subimage index out of range");
        const ImageSpec& sp = in->specs[s];
        if (sp.deep)
            return fail("deep images are not supported");
        // UINT channels (object ids) keep their bits: read natively and bit-cast into the
        // float buffer, where converting would normalise them to [0, 1]. Float channels are
        // asked for natively too: OpenImageIO lists per-channel formats for every EXR, even
        // all-float ones, and then reads "float as float" through a fresh conversion buffer
        // of up to 64 MB per call (over half a 4K file command's page faults).
        bool uint = false, all_float = true;
        for (int c = chbegin; c < chend; ++c) {
            uint |= sp.channelformat(c) == TypeDesc::UINT;
            all_float &= sp.channelformat(c) == TypeDesc::FLOAT;
        }
        std::vector<unsigned char> native;
        TypeDesc format = all_float ? TypeDesc::UNKNOWN : TypeDesc::FLOAT;
        void* target = data;
        size_t pixel_bytes = 0;
        if (uint) {
            for (int c = chbegin; c < chend; ++c)
                pixel_bytes += sp.channelformat(c).size();
            native.resize(size_t(yend - ybegin) * size_t(sp.width) * pixel_bytes);
            format = TypeDesc::UNKNOWN;
            target = native.data();
        }
        bool good;
        if (sp.tile_width > 0)
            good = in->in->read_tiles(s, 0, sp.x, sp.x + sp.width, ybegin, yend, sp.z, sp.z + 1,
                                      chbegin, chend, format, target);
        else
            good = in->in->read_scanlines(s, 0, ybegin, yend, sp.z, chbegin, chend, format, target);
        if (!good || in->in->has_error())
            return fail(in->in->geterror());
        if (uint) {
            const unsigned char* src = native.data();
            size_t n = size_t(yend - ybegin) * size_t(sp.width);
            float* dst = data;
            for (size_t i = 0; i < n; ++i)
                for (int c = chbegin; c < chend; ++c) {
                    TypeDesc t = sp.channelformat(c);
                    if (t == TypeDesc::UINT)
                        std::memcpy(dst, src, 4);
                    else if (t == TypeDesc::FLOAT)
                        std::memcpy(dst, src, 4);
                    else
                        convert_pixel_values(t, src, TypeDesc::FLOAT, dst, 1);
                    src += t.size();
                    dst += 1;
                }
        }
        return ok();
    });
}

namespace {
ImageSpec make_spec(const kpcn_output_spec* os) {
    ImageSpec spec(os->width, os->height, os->nchannels, TypeDesc::FLOAT);
    spec.x = os->x;
    spec.y = os->y;
    spec.full_x = os->full_x;
    spec.full_y = os->full_y;
    spec.full_width = os->full_width;
    spec.full_height = os->full_height;
    spec.channelnames.clear();
    spec.channelformats.clear();
    bool mixed = false;
    for (int c = 0; c < os->nchannels; ++c) {
        spec.channelnames.emplace_back(os->channel_names[c]);
        int f = os->channel_formats[c];
        TypeDesc t = f == KPCN_FORMAT_HALF ? TypeDesc::HALF : f == KPCN_FORMAT_UINT ? TypeDesc::UINT : TypeDesc::FLOAT;
        mixed |= t != TypeDesc::FLOAT;
        spec.channelformats.push_back(t);
    }
    if (!mixed)
        spec.channelformats.clear();  // uniform float: let spec.format speak
    spec.alpha_channel = -1;
    spec.z_channel = -1;
    for (int i = 0; i < os->nattributes; ++i) {
        const kpcn_attribute& a = os->attributes[i];
        if (a.is_string)
            spec.attribute(a.name, a.text);
        else if (a.data)
            spec.attribute(a.name, TypeDesc(a.type), a.data);
    }
    if (os->compression && *os->compression)
        spec.attribute("compression", os->compression);
    if (os->part_name && *os->part_name)
        spec.attribute("oiio:subimagename", os->part_name);
    return spec;
}
}  // namespace

int kpcn_output_open(const char* path, const kpcn_output_spec* specs, int nparts, int encoders,
                     kpcn_output** out) {
    return guarded([&]() {
        *out = nullptr;
        if (nparts < 1)
            return fail("an image needs at least one part");
        // OpenEXR sizes its pool from OIIO's `exr_threads` when a writer is made, and the
        // file keeps the thread count it saw: set for this writer, then put back.
        static std::mutex exr_threads_mutex;
        std::unique_lock<std::mutex> lock(exr_threads_mutex, std::defer_lock);
        int before = 0;
        if (encoders > 1) {
            lock.lock();
            OIIO::getattribute("exr_threads", before);
            OIIO::attribute("exr_threads", encoders);
        }
        auto o = ImageOutput::create("openexr");
        struct Restore {
            bool on;
            int value;
            ~Restore() {
                if (on)
                    OIIO::attribute("exr_threads", value);
            }
        } restore{encoders > 1, before};
        if (!o)
            return fail(OIIO::geterror());
        auto h = std::make_unique<kpcn_output>();
        for (int p = 0; p < nparts; ++p)
            h->specs.push_back(make_spec(&specs[p]));
        if (nparts > 1 && !o->supports("multiimage"))
            return fail("this OpenImageIO cannot write multi-part EXR");
        bool good = nparts == 1 ? o->open(path, h->specs[0])
                                : o->open(path, nparts, h->specs.data());
        if (!good)
            return fail(o->geterror());
        h->out = std::move(o);
        h->path = path;
        *out = h.release();
        return ok();
    });
}

int kpcn_output_next_part(kpcn_output* out) {
    return guarded([&]() {
        if (out->part + 1 >= int(out->specs.size()))
            return fail("no further part declared");
        out->part += 1;
        if (!out->out->open(out->path, out->specs[out->part], ImageOutput::AppendSubimage))
            return fail(out->out->geterror());
        return ok();
    });
}

int kpcn_output_write_rows(kpcn_output* out, int ybegin, int yend, const float* data) {
    return guarded([&]() {
        const ImageSpec& sp = out->specs[out->part];
        bool uint = false;
        for (const TypeDesc& t : sp.channelformats)
            uint |= t == TypeDesc::UINT;
        if (!uint) {
            if (!out->out->write_scanlines(ybegin, yend, 0, TypeDesc::FLOAT, data))
                return fail(out->out->geterror());
            return ok();
        }
        // UINT channels hold their bits in the float buffer (see kpcn_input_read_rows):
        // written natively, each channel in its own format.
        size_t pixel_bytes = 0;
        for (const TypeDesc& t : sp.channelformats)
            pixel_bytes += t.size();
        size_t n = size_t(yend - ybegin) * size_t(sp.width);
        std::vector<unsigned char> native(n * pixel_bytes);
        unsigned char* dst = native.data();
        const float* src = data;
        for (size_t i = 0; i < n; ++i)
            for (const TypeDesc& t : sp.channelformats) {
                if (t == TypeDesc::HALF) {
                    convert_pixel_values(TypeDesc::FLOAT, src, TypeDesc::HALF, dst, 1);
                } else {
                    std::memcpy(dst, src, 4);
                }
                dst += t.size();
                src += 1;
            }
        if (!out->out->write_scanlines(ybegin, yend, 0, TypeDesc::UNKNOWN, native.data()))
            return fail(out->out->geterror());
        return ok();
    });
}

int kpcn_output_close(kpcn_output* out) {
    if (!out)
        return ok();
    int status = guarded([&]() {
        if (!out->out->close())
            return fail(out->out->geterror());
        return ok();
    });
    delete out;
    return status;
}

}  // extern "C"
