// plugins/oiio/kpcn_imagebuf.h from a C++ tool (tests/plugins.rs builds and runs this):
// reads a native-layout EXR into ImageBufs, picks each pass by channel name (half data
// converted to float by the helper), denoises and writes the result.
//
//   imagebuf_test PASSES.exr OUT.exr
#include "kpcn_imagebuf.h"

#include <OpenImageIO/imagebufalgo.h>

#include <cstdio>

int main(int argc, char** argv) {
    if (argc != 3) return std::fprintf(stderr, "usage: imagebuf_test PASSES.exr OUT.exr\n"), 2;
    OIIO::ImageBuf src(argv[1]);
    auto pass = [&](std::initializer_list<const char*> names) {
        std::vector<int> order;
        for (const char* n : names) order.push_back(src.spec().channelindex(n));
        return OIIO::ImageBufAlgo::channels(src, int(order.size()), order);
    };
    // `channels` keeps the source's pixel type (half here): the helper converts it.
    OIIO::ImageBuf color = pass({"R", "G", "B"}), diffuse = pass({"diffuse.R", "diffuse.G", "diffuse.B"}),
                   albedo = pass({"albedo.R", "albedo.G", "albedo.B"}),
                   normal = pass({"normal.R", "normal.G", "normal.B"}), depth = pass({"depth.Z"});
    kpcn::ImageBufInputs in;
    in.color = &color;
    in.diffuse = &diffuse;
    in.albedo = &albedo;
    in.normal = &normal;
    in.depth = &depth;
    OIIO::ImageBuf out;
    std::string error;
    if (!kpcn::denoise(in, out, error)) return std::fprintf(stderr, "%s\n", error.c_str()), 1;
    if (!out.write(argv[2])) return std::fprintf(stderr, "%s\n", out.geterror().c_str()), 1;
    std::printf("ok\n");
    return 0;
}
