// bfr_peer: OpenSubdiv's Bfr (3.5, Debian libosd-dev) as a differential-testing oracle and benchmark peer for
// warp_subdiv.LimitSurface. Written from the Bfr headers' documentation; single-threaded.
//
// It reuses osd_peer.cpp's record files and mesh input (the file is included below, its main renamed), so a
// mesh is described exactly as for osd_peer (see that file's header: points, face_counts, face_indices,
// crease_pairs / crease_sharpness, corner_vertices / corner_sharpness, holes, scheme, vtx_boundary, creasing,
// triangle_sub, left_handed). The Far::TopologyRefiner is created unrefined, as Bfr::RefinerSurfaceFactory
// wants it; the factory has its default internal cache.
//
// ---------------------------------------------------------------------------------------------------------
// Usage
//
//   bfr_peer evaluate IN OUT
//       Evaluate the limit surface at the query points of IN (Bfr::Surface<double>::Evaluate with first and
//       second derivatives; one Surface per distinct face, points grouped by face).
//   bfr_peer tessellate IN OUT
//       Bfr::Tessellation of every face (uniform rate per face, or per-edge rates) and the surface at its
//       coordinates.
//   bfr_peer bench IN [--reps R]
//       Time Bfr's evaluation of the query points of IN; print one JSON object on stdout.
//   bfr_peer version
//
// Exit status as osd_peer: 0 success, 1 OpenSubdiv refused the input, 2 usage or file errors.
//
// Extra input records:
//   approx_smooth   i ()      SurfaceFactory::Options::SetApproxLevelSmooth   (default: Bfr's, 2)
//   approx_sharp    i ()      SurfaceFactory::Options::SetApproxLevelSharp    (default: Bfr's, 6)
//   query_faces     i (n,)    evaluate / bench: the face of every query point
//   query_uv        f (n, 2)  evaluate / bench: its (u, v) in the face's Bfr::Parameterization
//   rates           i (F,)    tessellate: uniform rate of every face (Tessellation(param, rate, options))
//   edge_rates      i (sum,)  tessellate: optional, one rate per face edge (edge i from vertex i to i + 1);
//                             with it the faces get Tessellation(param, N, edge_rates), inner rates inferred
//   preserve_quads  i ()      tessellate: Tessellation::Options::PreserveQuads (default 1)
//
// Output records of evaluate:
//   points, du, dv, duu, duv, dvv   f (n, 3)  Surface::Evaluate (zeros where invalid)
//   valid            i (n,)     1 where the face has a limit surface (not a hole)
//   face_regular     i (F,)     Surface::IsRegular (-1: no surface)
//   face_vertex_uv   f (sum, 2) Parameterization::GetVertexCoord of every face vertex
//   face_center_uv   f (F, 2)   Parameterization::GetCenterCoord
//   face_subfaces    i (F,)     Parameterization::HasSubFaces
// and, when the mesh has a face-varying channel (fvar_values, fvar_indices, fvar_linear as for osd_peer), the
// channel's limit at the same queries (InitFaceVaryingSurface of channel 0, one Surface per distinct face):
//   fvar_points, fvar_du, fvar_dv   f (n, e)  Surface::Evaluate of the channel's values (zeros where invalid)
//   fvar_valid       i (n,)     1 where the face has a face-varying surface
// Output records of tessellate (faces without a surface have no coordinates and facets):
//   coord_offsets    i (F+1,)   coordinates of face f: coord_offsets[f] .. coord_offsets[f+1]-1
//   coords           f (c, 2)   Tessellation::GetCoords (boundary coordinates first, counter-clockwise from
//                               vertex 0, then interior ones)
//   points           f (c, 3)   the surface at them
//   facet_offsets    i (F+1,)
//   facets           i (t, 4)   Tessellation::GetFacets, indices into the face's coordinates, size 4 with -1
//                               as the fourth index of triangles
// bench JSON: setup_s (TopologyRefiner + factory), and for "grouped" (points sorted by face, one Surface per
// face: InitVertexSurface, PreparePatchPoints, then Evaluate with first derivatives per point) and "per_point"
// (in the given order, InitVertexSurface and PreparePatchPoints for every point, the factory's cache
// warm) the best of R repetitions: seconds (wall, steady_clock), cpu_seconds (std::clock, the process's CPU
// time: the fair figure on a shared machine) and points_per_second (from the wall time).
// ---------------------------------------------------------------------------------------------------------

#define main osd_peer_main
#include "osd_peer.cpp"
#undef main

#include <opensubdiv/bfr/parameterization.h>
#include <opensubdiv/bfr/refinerSurfaceFactory.h>
#include <opensubdiv/bfr/surface.h>
#include <opensubdiv/bfr/tessellation.h>

#include <ctime>
#include <numeric>

namespace {

using SurfaceFactory = Bfr::RefinerSurfaceFactory<>;
using Surface = Bfr::Surface<double>;

struct Bfr3 {
    MeshInput mesh;
    std::unique_ptr<Far::TopologyRefiner> refiner;
    std::unique_ptr<SurfaceFactory> factory;
};

SurfaceFactory::Options factoryOptions(const Records &r) {
    SurfaceFactory::Options o;
    if (find(r, "approx_smooth", 'i', 0)) o.SetApproxLevelSmooth(option(r, "approx_smooth", 2, 0, 10));
    if (find(r, "approx_sharp", 'i', 0)) o.SetApproxLevelSharp(option(r, "approx_sharp", 6, 0, 10));
    return o;
}

void setUp(const Records &r, Bfr3 &b) {
    loadMesh(r, b.mesh);
    if (b.mesh.width != 3) throw UsageError("points must be (n, 3)");
    b.refiner.reset(createRefiner(b.mesh));
    b.factory.reset(new SurfaceFactory(*b.refiner, factoryOptions(r)));
}

struct Queries {
    std::vector<int> faces;
    std::vector<double> uv;
};

Queries loadQueries(const Records &r, int numFaces) {
    Queries q;
    q.faces = need(r, "query_faces", 'i', 1).ints;
    const Array &uv = need(r, "query_uv", 'f', 2);
    if (uv.shape[0] != (int64_t)q.faces.size() || uv.shape[1] != 2) throw UsageError("query_uv must be (n, 2)");
    q.uv = uv.reals;
    for (int f : q.faces)
        if (f < 0 || f >= numFaces) throw UsageError("query_faces refer to a missing face");
    return q;
}

// ------------------------------------------------------------------------------------------- evaluate
void evaluate(const std::string &inPath, const std::string &outPath) {
    Records r = readRecords(inPath);
    Bfr3 b;
    setUp(r, b);
    const int F = b.refiner->GetLevel(0).GetNumFaces();
    Queries q = loadQueries(r, F);
    const size_t n = q.faces.size();
    std::vector<double> P(3 * n, 0.0), Du(3 * n, 0.0), Dv(3 * n, 0.0), Duu(3 * n, 0.0), Duv(3 * n, 0.0),
        Dvv(3 * n, 0.0);
    std::vector<int32_t> valid(n, 0), regular(F, -1), subfaces(F, 0);
    std::vector<double> vertexUV, centerUV(2 * F, 0.0);
    for (int f = 0; f < F; ++f) {
        Bfr::Parameterization param(b.refiner->GetSchemeType(), b.mesh.counts[f]);
        for (int i = 0; i < b.mesh.counts[f]; ++i) {
            double uv[2];
            param.GetVertexCoord(i, uv);
            vertexUV.push_back(uv[0]);
            vertexUV.push_back(uv[1]);
        }
        param.GetCenterCoord(&centerUV[2 * f]);
        subfaces[f] = param.HasSubFaces() ? 1 : 0;
    }
    std::vector<size_t> order(n);
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t c) { return q.faces[a] < q.faces[c]; });
    Surface surface;
    std::vector<double> patchPoints;
    int current = -1;
    bool ok = false;
    for (size_t k : order) {
        int f = q.faces[k];
        if (f != current) {
            current = f;
            ok = b.factory->InitVertexSurface(f, &surface) && surface.IsValid();
            if (ok) {
                regular[f] = surface.IsRegular() ? 1 : 0;
                patchPoints.resize(3 * (size_t)surface.GetNumPatchPoints());
                surface.PreparePatchPoints(b.mesh.points.data(), 3, patchPoints.data(), 3);
            }
        }
        if (!ok) continue;
        valid[k] = 1;
        surface.Evaluate(&q.uv[2 * k], patchPoints.data(), 3, &P[3 * k], &Du[3 * k], &Dv[3 * k], &Duu[3 * k],
                         &Duv[3 * k], &Dvv[3 * k]);
    }
    // the face-varying channel: its own Surface per face (the values' topology and the interpolation mode)
    const int E = b.mesh.fvarWidth;
    std::vector<double> FP((size_t)E * n, 0.0), FDu((size_t)E * n, 0.0), FDv((size_t)E * n, 0.0);
    std::vector<int32_t> fvalid(n, 0);
    if (b.mesh.hasFVar()) {
        current = -1;
        ok = false;
        for (size_t k : order) {
            int f = q.faces[k];
            if (f != current) {
                current = f;
                ok = b.factory->InitFaceVaryingSurface(f, &surface, 0) && surface.IsValid();
                if (ok) {
                    patchPoints.resize((size_t)E * (size_t)surface.GetNumPatchPoints());
                    surface.PreparePatchPoints(b.mesh.fvarValues.data(), E, patchPoints.data(), E);
                }
            }
            if (!ok) continue;
            fvalid[k] = 1;
            surface.Evaluate(&q.uv[2 * k], patchPoints.data(), E, &FP[E * k], &FDu[E * k], &FDv[E * k]);
        }
    }
    RecordWriter w(outPath);
    const int64_t N = (int64_t)n;
    if (b.mesh.hasFVar()) {
        w.reals("fvar_points", {N, E}, FP.data());
        w.reals("fvar_du", {N, E}, FDu.data());
        w.reals("fvar_dv", {N, E}, FDv.data());
        w.ints("fvar_valid", {N}, fvalid.data());
    }
    w.reals("points", {N, 3}, P.data());
    w.reals("du", {N, 3}, Du.data());
    w.reals("dv", {N, 3}, Dv.data());
    w.reals("duu", {N, 3}, Duu.data());
    w.reals("duv", {N, 3}, Duv.data());
    w.reals("dvv", {N, 3}, Dvv.data());
    w.ints("valid", {N}, valid.data());
    w.ints("face_regular", {F}, regular.data());
    w.reals("face_vertex_uv", {(int64_t)vertexUV.size() / 2, 2}, vertexUV.data());
    w.reals("face_center_uv", {F, 2}, centerUV.data());
    w.ints("face_subfaces", {F}, subfaces.data());
    w.close();
}

// ----------------------------------------------------------------------------------------- tessellate
void tessellate(const std::string &inPath, const std::string &outPath) {
    Records r = readRecords(inPath);
    Bfr3 b;
    setUp(r, b);
    const int F = b.refiner->GetLevel(0).GetNumFaces();
    const std::vector<int32_t> &rates = need(r, "rates", 'i', 1).ints;
    if ((int)rates.size() != F) throw UsageError("rates must have one entry per face");
    const Array *edgeRates = find(r, "edge_rates", 'i', 1);
    if (edgeRates && edgeRates->count() != (int64_t)b.mesh.indices.size())
        throw UsageError("edge_rates must have one entry per face edge");
    Bfr::Tessellation::Options topts;
    topts.PreserveQuads(option(r, "preserve_quads", 1, 0, 1) != 0);
    topts.SetFacetSize(4);
    std::vector<int32_t> coordOffsets(1, 0), facetOffsets(1, 0), facets;
    std::vector<double> coords, points;
    Surface surface;
    std::vector<double> patchPoints;
    int start = 0;
    for (int f = 0; f < F; ++f) {
        const int nv = b.mesh.counts[f];
        if (b.factory->InitVertexSurface(f, &surface) && surface.IsValid()) {
            std::unique_ptr<Bfr::Tessellation> t;
            if (edgeRates)
                t.reset(new Bfr::Tessellation(surface.GetParameterization(), nv, &edgeRates->ints[start], topts));
            else
                t.reset(new Bfr::Tessellation(surface.GetParameterization(), rates[f], topts));
            const int nc = t->GetNumCoords();
            std::vector<double> uv(2 * (size_t)nc);
            t->GetCoords(uv.data());
            patchPoints.resize(3 * (size_t)surface.GetNumPatchPoints());
            surface.PreparePatchPoints(b.mesh.points.data(), 3, patchPoints.data(), 3);
            for (int i = 0; i < nc; ++i) {
                double p[3];
                surface.Evaluate(&uv[2 * i], patchPoints.data(), 3, p);
                points.insert(points.end(), p, p + 3);
            }
            coords.insert(coords.end(), uv.begin(), uv.end());
            std::vector<int> fac(4 * (size_t)t->GetNumFacets());
            t->GetFacets(fac.data());
            facets.insert(facets.end(), fac.begin(), fac.end());
            coordOffsets.push_back(coordOffsets.back() + nc);
            facetOffsets.push_back(facetOffsets.back() + t->GetNumFacets());
        } else {
            coordOffsets.push_back(coordOffsets.back());
            facetOffsets.push_back(facetOffsets.back());
        }
        start += nv;
    }
    RecordWriter w(outPath);
    w.ints("coord_offsets", {F + 1}, coordOffsets.data());
    w.reals("coords", {(int64_t)coords.size() / 2, 2}, coords.data());
    w.reals("points", {(int64_t)points.size() / 3, 3}, points.data());
    w.ints("facet_offsets", {F + 1}, facetOffsets.data());
    w.ints("facets", {(int64_t)facets.size() / 4, 4}, facets.data());
    w.close();
}

// ---------------------------------------------------------------------------------------------- bench
int benchBfr(int argc, char **argv) {
    if (argc < 3) throw UsageError("bench needs an input file");
    int reps = 3;
    for (int i = 3; i < argc; ++i) {
        std::string a = argv[i];
        if (a == "--reps" && i + 1 < argc)
            reps = std::max(1, std::atoi(argv[++i]));
        else
            throw UsageError("unknown bench option " + a);
    }
    Records r = readRecords(argv[2]);
    auto t0 = Clock::now();
    Bfr3 b;
    setUp(r, b);
    auto t1 = Clock::now();
    const int F = b.refiner->GetLevel(0).GetNumFaces();
    Queries q = loadQueries(r, F);
    const size_t n = q.faces.size();
    std::vector<double> out(9 * n);
    Surface surface;
    std::vector<double> patchPoints;
    double bestGrouped = 1e300, bestPerPoint = 1e300, checksum = 0.0;
    double cpuGrouped = 1e300, cpuPerPoint = 1e300;
    for (int rep = 0; rep < reps; ++rep) {
        auto a = Clock::now();
        std::clock_t ca = std::clock();
        std::vector<size_t> order(n);
        std::iota(order.begin(), order.end(), 0);
        std::stable_sort(order.begin(), order.end(), [&](size_t x, size_t y) { return q.faces[x] < q.faces[y]; });
        int current = -1;
        bool ok = false;
        for (size_t k : order) {
            int f = q.faces[k];
            if (f != current) {
                current = f;
                ok = b.factory->InitVertexSurface(f, &surface) && surface.IsValid();
                if (ok) {
                    patchPoints.resize(3 * (size_t)surface.GetNumPatchPoints());
                    surface.PreparePatchPoints(b.mesh.points.data(), 3, patchPoints.data(), 3);
                }
            }
            if (ok) surface.Evaluate(&q.uv[2 * k], patchPoints.data(), 3, &out[9 * k], &out[9 * k + 3], &out[9 * k + 6]);
        }
        bestGrouped = std::min(bestGrouped, seconds(a, Clock::now()));
        cpuGrouped = std::min(cpuGrouped, double(std::clock() - ca) / CLOCKS_PER_SEC);
        a = Clock::now();
        ca = std::clock();
        for (size_t k = 0; k < n; ++k) {
            if (b.factory->InitVertexSurface(q.faces[k], &surface) && surface.IsValid()) {
                patchPoints.resize(3 * (size_t)surface.GetNumPatchPoints());
                surface.PreparePatchPoints(b.mesh.points.data(), 3, patchPoints.data(), 3);
                surface.Evaluate(&q.uv[2 * k], patchPoints.data(), 3, &out[9 * k], &out[9 * k + 3], &out[9 * k + 6]);
            }
        }
        bestPerPoint = std::min(bestPerPoint, seconds(a, Clock::now()));
        cpuPerPoint = std::min(cpuPerPoint, double(std::clock() - ca) / CLOCKS_PER_SEC);
    }
    for (double v : out) checksum += v;
    std::ostringstream js;
    js << "{\"opensubdiv\": \"" << OPENSUBDIV_VERSION_MAJOR << "." << OPENSUBDIV_VERSION_MINOR << "."
       << OPENSUBDIV_VERSION_PATCH << "\", \"faces\": " << F << ", \"points\": " << n << ", \"reps\": " << reps
       << ", \"setup_s\": " << num(seconds(t0, t1)) << ", \"grouped\": {\"seconds\": " << num(bestGrouped)
       << ", \"cpu_seconds\": " << num(cpuGrouped) << ", \"points_per_second\": " << num(n / bestGrouped)
       << "}, \"per_point\": {\"seconds\": " << num(bestPerPoint) << ", \"cpu_seconds\": " << num(cpuPerPoint)
       << ", \"points_per_second\": " << num(n / bestPerPoint) << "}, \"checksum\": " << num(checksum) << "}";
    std::printf("%s\n", js.str().c_str());
    return 0;
}

int bfrUsage() {
    std::fprintf(stderr,
                 "usage: bfr_peer evaluate IN OUT\n"
                 "       bfr_peer tessellate IN OUT\n"
                 "       bfr_peer bench IN [--reps R]\n"
                 "       bfr_peer version\n");
    return 2;
}

}  // namespace

int main(int argc, char **argv) {
    Far::SetErrorCallback(onOsdError);
    Far::SetWarningCallback(onOsdWarning);
    if (argc < 2) return bfrUsage();
    std::string mode = argv[1];
    try {
        if (mode == "evaluate" && argc == 4) {
            evaluate(argv[2], argv[3]);
            return 0;
        }
        if (mode == "tessellate" && argc == 4) {
            tessellate(argv[2], argv[3]);
            return 0;
        }
        if (mode == "bench") return benchBfr(argc, argv);
        if (mode == "version") {
            std::printf("%d.%d.%d\n", OPENSUBDIV_VERSION_MAJOR, OPENSUBDIV_VERSION_MINOR, OPENSUBDIV_VERSION_PATCH);
            return 0;
        }
        return bfrUsage();
    } catch (const OsdError &e) {
        std::fprintf(stderr, "bfr_peer: %s\n", e.what());
        return 1;
    } catch (const std::exception &e) {
        std::fprintf(stderr, "bfr_peer: %s\n", e.what());
        return 2;
    }
}
