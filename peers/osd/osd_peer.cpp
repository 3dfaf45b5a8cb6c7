// osd_peer: OpenSubdiv (3.5, Debian libosd-dev) as a differential-testing oracle and benchmark peer for
// warp-subdiv. Written from OpenSubdiv's API documentation (the Far/Osd/Sdc headers); single-threaded.
//
// ---------------------------------------------------------------------------------------------------------
// Usage
//
//   osd_peer refine IN OUT [IN OUT ...]
//       For every (IN, OUT) pair: read a mesh file, refine it uniformly to its "level" and write every level.
//   osd_peer bench IN [--level N] [--reps R] [--budget-mb M] [--factorized last|all]
//       Time OpenSubdiv's refinement paths on one mesh; print one JSON object on stdout.
//   osd_peer version
//       Print the OpenSubdiv version this binary was built against.
//
// Exit status: 0 success, 1 OpenSubdiv refused the input (topology error), 2 usage or file errors. Errors are
// one line on stderr; OpenSubdiv's own warnings go to stderr prefixed "osd warning:".
//
// ---------------------------------------------------------------------------------------------------------
// File format (input and output): a record stream, all numbers little-endian.
//
//   8 bytes  magic "OSDPEER1"
//   records until end of file, each:
//     uint32   name length L, then L bytes of ASCII name
//     uint8    type: 'i' (int32) or 'f' (float64)
//     uint32   ndim, then ndim x int64 dimensions (ndim 0 = a scalar)
//     data     prod(dims) values of the type, C order
//
// Input records (a missing optional record means "none"):
//   points            f (n, d)  vertex data, any width d >= 1 (d = 3 for bench)
//   face_counts       i (F,)    vertices per face
//   face_indices      i (sum,)  vertex ids, faces one after another
//   crease_pairs      i (m, 2)  optional; edge vertex pairs
//   crease_sharpness  f (m,)    sharpness per pair (>= 10 is infinitely sharp in OpenSubdiv)
//   corner_vertices   i (c,)    optional
//   corner_sharpness  f (c,)
//   holes             i (h,)    optional; face ids
//   fvar_values       f (k, e)  optional face-varying channel: values ...
//   fvar_indices      i (sum,)  ... and one value id per face-vertex (same layout as face_indices)
//   scheme            i ()      Sdc::SchemeType: 0 bilinear, 1 catmark, 2 loop                 (default 1)
//   vtx_boundary      i ()      Sdc::Options::VtxBoundaryInterpolation: 0 none, 1 edge-only,
//                               2 edge-and-corner                                            (default 2)
//   creasing          i ()      Sdc::Options::CreasingMethod: 0 uniform, 1 chaikin            (default 0)
//   fvar_linear       i ()      Sdc::Options::FVarLinearInterpolation: 0 none, 1 corners-only,
//                               2 corners-plus1, 3 corners-plus2, 4 boundaries, 5 all         (default 5)
//   triangle_sub      i ()      Sdc::Options::TriangleSubdivision: 0 catmark, 1 smooth         (default 0)
//   left_handed       i ()      TopologyDescriptor::isLeftHanded                               (default 0)
//   level             i ()      uniform refinement level N, 0..10                              (default 1)
//   limit             i ()      1: also write limit positions and tangents of level N          (default 0)
//
// Output records of refine (L = 0..N; level 0 is the control mesh as OpenSubdiv sees it):
//   num_levels            i ()      N + 1
//   L<L>/points           f (nv, d) PrimvarRefinerReal<double>::Interpolate, level by level, in float64
//                                   (RefineUniform with fullTopologyInLastLevel = true, other options default)
//   L<L>/face_counts      i (F,)    all faces of the level, hole faces included ...
//   L<L>/face_indices     i (sum,)
//   L<L>/face_holes       i (F,)    ... flagged 1 here (TopologyLevel::IsFaceHole)
//   L<L>/vertex_rules     i (nv,)   TopologyLevel::GetVertexRule (Sdc::Crease::Rule bits: 1 smooth, 2 dart,
//                                   4 crease, 8 corner)
//   L<L>/vertex_boundary  i (nv,)   TopologyLevel::IsVertexBoundary
//   L<L>/vertex_nonmanifold i (nv,) TopologyLevel::IsVertexNonManifold
//   L<L>/vertex_sharpness f (nv,)   TopologyLevel::GetVertexSharpness (10 = infinitely sharp)
//   L<L>/edge_vertices    i (E, 2)  TopologyLevel::GetEdgeVertices, and ...
//   L<L>/edge_sharpness   f (E,)    ... GetEdgeSharpness after OpenSubdiv's own sharpening (boundary and
//                                   non-manifold edges 10)
//   L<L>/fvar_values      f (k, e)  when a face-varying channel was given: InterpolateFaceVarying
//   L<L>/fvar_indices     i (sum,)  TopologyLevel::GetFaceFVarValues, per face-vertex
//   limit/points          f (nv, d) when limit = 1: PrimvarRefinerReal<double>::Limit(src, pos, tan1, tan2)
//   limit/tan1            f (nv, d)   on level N; OpenSubdiv leaves
//   limit/tan2            f (nv, d)   vertices without edges at their refined position with zero tangents
//
// ---------------------------------------------------------------------------------------------------------
// bench: all phases single-threaded, float32 xyz data, std::chrono::steady_clock, best of R repetitions.
//   (a) topology           TopologyRefinerFactory<TopologyDescriptor>::Create + RefineUniform(level N),
//                          UniformOptions defaults (fullTopologyInLastLevel = false); the delete is not timed.
//   (b) interpolate        table-free: PrimvarRefiner (float) ::Interpolate level 1..N into per-level
//                          float xyz buffers allocated once outside the timer.
//   (c) per_level_stencils StencilTableFactory::Create with Options: generateIntermediateLevels = true,
//                          factorizeIntermediateLevels = false, generateControlVerts = false,
//                          generateOffsets = true, maxLevel = N (others default). With these options level
//                          k's stencils index level k-1's vertices (0-based within that level), so they are
//                          evaluated level by level: Osd::CpuEvaluator::EvalStencils(raw pointers, start,
//                          end) from level k-1's buffer into level k's. Build and evaluation timed apart.
//   (d) factorized_stencils
//                          "last" (default; what Osd::Mesh uses for uniform refinement): factory defaults
//                          except generateOffsets = true, generateIntermediateLevels = false, maxLevel = N:
//                          one table of level N's vertices, each factorised over the control vertices,
//                          evaluated with one EvalStencils call. "all": factory defaults (every level
//                          1..N, each factorised over the control vertices) except generateOffsets = true,
//                          maxLevel = N. Skipped (reported with the estimate) when the estimated build
//                          memory exceeds --budget-mb (default 2048): the estimate is 3 x (stencil count x
//                          average stencil size measured on a factorised level-min(N, 2) table x 8 bytes
//                          + 8 bytes per stencil).
//   (c) and (d) report stencils, entries (the sum of the stencil sizes), table_bytes (the four vectors as
//   held: OpenSubdiv 3.5 may leave the weight vector longer than the entries) and the largest absolute
//   difference of their level-N points from (b)'s.
//   peak_rss_bytes: getrusage(RUSAGE_SELF).ru_maxrss, after each phase and at the end.
// ---------------------------------------------------------------------------------------------------------

#include <opensubdiv/far/error.h>
#include <opensubdiv/far/primvarRefiner.h>
#include <opensubdiv/far/stencilTable.h>
#include <opensubdiv/far/stencilTableFactory.h>
#include <opensubdiv/far/topologyDescriptor.h>
#include <opensubdiv/osd/bufferDescriptor.h>
#include <opensubdiv/osd/cpuEvaluator.h>
#include <opensubdiv/version.h>

#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace OpenSubdiv;

namespace {

// ----------------------------------------------------------------------------------------------- errors
struct UsageError : std::runtime_error {
    using std::runtime_error::runtime_error;
};
struct OsdError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

std::string g_lastOsdError;

void onOsdError(Far::ErrorType, const char *message) {
    g_lastOsdError = message ? message : "unknown error";
    std::fprintf(stderr, "osd error: %s\n", g_lastOsdError.c_str());
}

void onOsdWarning(const char *message) { std::fprintf(stderr, "osd warning: %s\n", message ? message : ""); }

// ------------------------------------------------------------------------------------------- record files
const char kMagic[8] = {'O', 'S', 'D', 'P', 'E', 'E', 'R', '1'};

struct Array {
    char type = 'i';
    std::vector<int64_t> shape;
    std::vector<int32_t> ints;
    std::vector<double> reals;

    int64_t count() const {
        int64_t n = 1;
        for (int64_t s : shape) n *= s;
        return n;
    }
};

using Records = std::map<std::string, Array>;

template <typename T>
void readRaw(FILE *fh, T *out, size_t n, const std::string &path) {
    if (n && std::fread(out, sizeof(T), n, fh) != n) throw UsageError(path + ": truncated record file");
}

Records readRecords(const std::string &path) {
    FILE *fh = std::fopen(path.c_str(), "rb");
    if (!fh) throw UsageError("cannot open " + path);
    std::unique_ptr<FILE, int (*)(FILE *)> guard(fh, std::fclose);
    char magic[8];
    readRaw(fh, magic, 8, path);
    if (std::memcmp(magic, kMagic, 8) != 0) throw UsageError(path + ": not an OSDPEER1 record file");
    Records out;
    for (;;) {
        uint32_t nameLen;
        if (std::fread(&nameLen, 4, 1, fh) != 1) break;  // clean end of file
        if (nameLen == 0 || nameLen > 256) throw UsageError(path + ": bad record name length");
        std::string name(nameLen, '\0');
        readRaw(fh, &name[0], nameLen, path);
        Array a;
        uint8_t type;
        uint32_t ndim;
        readRaw(fh, &type, 1, path);
        readRaw(fh, &ndim, 1, path);
        if ((type != 'i' && type != 'f') || ndim > 8) throw UsageError(path + ": bad header of record " + name);
        a.type = (char)type;
        a.shape.resize(ndim);
        readRaw(fh, a.shape.data(), ndim, path);
        for (int64_t s : a.shape)
            if (s < 0 || s > (int64_t(1) << 34)) throw UsageError(path + ": bad shape of record " + name);
        if (a.type == 'i') {
            a.ints.resize(a.count());
            readRaw(fh, a.ints.data(), a.ints.size(), path);
        } else {
            a.reals.resize(a.count());
            readRaw(fh, a.reals.data(), a.reals.size(), path);
        }
        out[name] = std::move(a);
    }
    return out;
}

class RecordWriter {
public:
    explicit RecordWriter(const std::string &path) : _path(path), _fh(std::fopen(path.c_str(), "wb")) {
        if (!_fh) throw UsageError("cannot write " + path);
        write(kMagic, 8);
    }
    ~RecordWriter() {
        if (_fh) std::fclose(_fh);
    }
    void close() {
        if (std::fclose(_fh) != 0) throw UsageError("cannot write " + _path);
        _fh = nullptr;
    }
    void ints(const std::string &name, std::vector<int64_t> shape, const int32_t *data) {
        header(name, 'i', shape);
        write(data, sizeof(int32_t) * count(shape));
    }
    void reals(const std::string &name, std::vector<int64_t> shape, const double *data) {
        header(name, 'f', shape);
        write(data, sizeof(double) * count(shape));
    }
    void scalar(const std::string &name, int32_t value) { ints(name, {}, &value); }

private:
    static size_t count(const std::vector<int64_t> &shape) {
        size_t n = 1;
        for (int64_t s : shape) n *= (size_t)s;
        return n;
    }
    void write(const void *data, size_t bytes) {
        if (bytes && std::fwrite(data, 1, bytes, _fh) != bytes) throw UsageError("cannot write " + _path);
    }
    void header(const std::string &name, char type, const std::vector<int64_t> &shape) {
        uint32_t len = (uint32_t)name.size();
        uint8_t t = (uint8_t)type;
        uint32_t ndim = (uint32_t)shape.size();
        write(&len, 4);
        write(name.data(), len);
        write(&t, 1);
        write(&ndim, 4);
        write(shape.data(), 8 * shape.size());
    }
    std::string _path;
    FILE *_fh;
};

// ------------------------------------------------------------------------------------------------ the mesh
const Array *find(const Records &r, const char *name, char type, int ndim) {
    auto it = r.find(name);
    if (it == r.end()) return nullptr;
    const Array &a = it->second;
    if (a.type != type || (ndim >= 0 && (int)a.shape.size() != ndim))
        throw UsageError(std::string("record ") + name + " has the wrong type or rank");
    return &a;
}

const Array &need(const Records &r, const char *name, char type, int ndim) {
    const Array *a = find(r, name, type, ndim);
    if (!a) throw UsageError(std::string("missing record ") + name);
    return *a;
}

int option(const Records &r, const char *name, int fallback, int lo, int hi) {
    const Array *a = find(r, name, 'i', 0);
    if (!a) return fallback;
    int v = a->ints[0];
    if (v < lo || v > hi) throw UsageError(std::string("option ") + name + " out of range");
    return v;
}

// Everything the TopologyDescriptor points to, kept alive together with it.
struct MeshInput {
    int numVertices = 0, width = 0, fvarWidth = 0, level = 1;
    bool limit = false;
    std::vector<double> points, fvarValues;
    std::vector<int> counts, indices, creasePairs, corners, holes, fvarIndices;
    std::vector<float> creaseWeights, cornerWeights;
    Sdc::SchemeType scheme = Sdc::SCHEME_CATMARK;
    Sdc::Options options;
    bool leftHanded = false;
    Far::TopologyDescriptor::FVarChannel channel;
    Far::TopologyDescriptor desc;

    bool hasFVar() const { return fvarWidth > 0; }
};

void loadMesh(const Records &r, MeshInput &m) {
    const Array &pts = need(r, "points", 'f', 2);
    m.numVertices = (int)pts.shape[0];
    m.width = (int)pts.shape[1];
    if (m.width < 1) throw UsageError("points need at least one column");
    m.points = pts.reals;
    m.counts = need(r, "face_counts", 'i', 1).ints;
    m.indices = need(r, "face_indices", 'i', 1).ints;
    int64_t total = 0;
    for (int c : m.counts) {
        if (c < 3) throw UsageError("a face has fewer than 3 vertices");
        total += c;
    }
    if (total != (int64_t)m.indices.size()) throw UsageError("face_counts do not add up to face_indices");
    for (int v : m.indices)
        if (v < 0 || v >= m.numVertices) throw UsageError("face_indices refer to a missing vertex");

    if (const Array *c = find(r, "crease_pairs", 'i', 2)) {
        if (c->count() && c->shape[1] != 2) throw UsageError("crease_pairs must be (m, 2)");
        m.creasePairs = c->ints;
        const Array &s = need(r, "crease_sharpness", 'f', 1);
        if (s.count() != c->shape[0]) throw UsageError("crease_sharpness does not match crease_pairs");
        m.creaseWeights.assign(s.reals.begin(), s.reals.end());
    }
    if (const Array *c = find(r, "corner_vertices", 'i', 1)) {
        m.corners = c->ints;
        const Array &s = need(r, "corner_sharpness", 'f', 1);
        if (s.count() != c->count()) throw UsageError("corner_sharpness does not match corner_vertices");
        m.cornerWeights.assign(s.reals.begin(), s.reals.end());
    }
    for (int v : m.creasePairs)
        if (v < 0 || v >= m.numVertices) throw UsageError("crease_pairs refer to a missing vertex");
    for (int v : m.corners)
        if (v < 0 || v >= m.numVertices) throw UsageError("corner_vertices refer to a missing vertex");
    if (const Array *h = find(r, "holes", 'i', 1)) m.holes = h->ints;
    for (int f : m.holes)
        if (f < 0 || f >= (int)m.counts.size()) throw UsageError("holes refer to a missing face");

    if (const Array *fv = find(r, "fvar_values", 'f', 2)) {
        m.fvarWidth = (int)fv->shape[1];
        if (m.fvarWidth < 1) throw UsageError("fvar_values need at least one column");
        m.fvarValues = fv->reals;
        m.fvarIndices = need(r, "fvar_indices", 'i', 1).ints;
        if (m.fvarIndices.size() != m.indices.size()) throw UsageError("fvar_indices must match face_indices");
        for (int v : m.fvarIndices)
            if (v < 0 || v >= fv->shape[0]) throw UsageError("fvar_indices refer to a missing value");
    }

    m.scheme = (Sdc::SchemeType)option(r, "scheme", Sdc::SCHEME_CATMARK, 0, 2);
    m.options.SetVtxBoundaryInterpolation(
        (Sdc::Options::VtxBoundaryInterpolation)option(r, "vtx_boundary", 2, 0, 2));
    m.options.SetCreasingMethod((Sdc::Options::CreasingMethod)option(r, "creasing", 0, 0, 1));
    m.options.SetFVarLinearInterpolation((Sdc::Options::FVarLinearInterpolation)option(r, "fvar_linear", 5, 0, 5));
    m.options.SetTriangleSubdivision((Sdc::Options::TriangleSubdivision)option(r, "triangle_sub", 0, 0, 1));
    m.leftHanded = option(r, "left_handed", 0, 0, 1) != 0;
    m.level = option(r, "level", 1, 0, 10);
    m.limit = option(r, "limit", 0, 0, 1) != 0;

    Far::TopologyDescriptor &d = m.desc;
    d.numVertices = m.numVertices;
    d.numFaces = (int)m.counts.size();
    d.numVertsPerFace = m.counts.data();
    d.vertIndicesPerFace = m.indices.data();
    d.numCreases = (int)m.creaseWeights.size();
    d.creaseVertexIndexPairs = m.creasePairs.data();
    d.creaseWeights = m.creaseWeights.data();
    d.numCorners = (int)m.corners.size();
    d.cornerVertexIndices = m.corners.data();
    d.cornerWeights = m.cornerWeights.data();
    d.numHoles = (int)m.holes.size();
    d.holeIndices = m.holes.data();
    d.isLeftHanded = m.leftHanded;
    if (m.hasFVar()) {
        m.channel.numValues = (int)(m.fvarValues.size() / m.fvarWidth);
        m.channel.valueIndices = m.fvarIndices.data();
        d.numFVarChannels = 1;
        d.fvarChannels = &m.channel;
    }
}

Far::TopologyRefiner *createRefiner(const MeshInput &m) {
    using Factory = Far::TopologyRefinerFactory<Far::TopologyDescriptor>;
    g_lastOsdError.clear();
    Far::TopologyRefiner *refiner = Factory::Create(m.desc, Factory::Options(m.scheme, m.options));
    if (!refiner) throw OsdError("TopologyRefinerFactory::Create failed: " + g_lastOsdError);
    return refiner;
}

// ----------------------------------------------------------------------------------- primvar buffers
// Rows of `width` doubles in one flat array, as PrimvarRefinerReal's templated buffer interface wants them:
// buffer[i] is a light reference with Clear() and AddWithWeight().
struct RowRef {
    double *p;
    int n;
    void Clear() { std::fill(p, p + n, 0.0); }
    void AddWithWeight(const RowRef &src, double w) {
        for (int k = 0; k < n; ++k) p[k] += w * src.p[k];
    }
};

struct Rows {
    double *base;
    int width;
    RowRef operator[](int i) const { return RowRef{base + (size_t)i * width, width}; }
};

// A float xyz vertex for the benchmark's table-free path.
struct Vec3f {
    float x, y, z;
    void Clear() { x = y = z = 0.f; }
    void AddWithWeight(const Vec3f &s, float w) {
        x += w * s.x;
        y += w * s.y;
        z += w * s.z;
    }
};

// --------------------------------------------------------------------------------------------- refine
void refineOne(const std::string &inPath, const std::string &outPath) {
    MeshInput m;
    loadMesh(readRecords(inPath), m);
    std::unique_ptr<Far::TopologyRefiner> refiner(createRefiner(m));
    Far::TopologyRefiner::UniformOptions uopts(m.level);
    // the last level's full topology: PrimvarRefiner::Limit needs it, and so do the edge and vertex records
    uopts.fullTopologyInLastLevel = true;
    refiner->RefineUniform(uopts);
    const int N = refiner->GetMaxLevel();

    // vertex data of every level, float64
    std::vector<std::vector<double>> pts(N + 1);
    pts[0] = m.points;
    Far::PrimvarRefinerReal<double> primvar(*refiner);
    for (int L = 1; L <= N; ++L) {
        pts[L].assign((size_t)refiner->GetLevel(L).GetNumVertices() * m.width, 0.0);
        Rows src{pts[L - 1].data(), m.width}, dst{pts[L].data(), m.width};
        primvar.Interpolate(L, src, dst);
    }
    std::vector<std::vector<double>> fvar(N + 1);
    if (m.hasFVar()) {
        fvar[0] = m.fvarValues;
        for (int L = 1; L <= N; ++L) {
            fvar[L].assign((size_t)refiner->GetLevel(L).GetNumFVarValues(0) * m.fvarWidth, 0.0);
            Rows src{fvar[L - 1].data(), m.fvarWidth}, dst{fvar[L].data(), m.fvarWidth};
            primvar.InterpolateFaceVarying(L, src, dst, 0);
        }
    }

    RecordWriter out(outPath);
    out.scalar("num_levels", N + 1);
    for (int L = 0; L <= N; ++L) {
        const Far::TopologyLevel &lvl = refiner->GetLevel(L);
        const std::string pre = "L" + std::to_string(L) + "/";
        const int nv = lvl.GetNumVertices(), nf = lvl.GetNumFaces();
        out.reals(pre + "points", {nv, m.width}, pts[L].data());
        std::vector<int32_t> counts(nf), holes(nf), indices, fvIdx;
        indices.reserve(lvl.GetNumFaceVertices());
        for (int f = 0; f < nf; ++f) {
            Far::ConstIndexArray fv = lvl.GetFaceVertices(f);
            counts[f] = fv.size();
            holes[f] = lvl.IsFaceHole(f) ? 1 : 0;
            for (int k = 0; k < fv.size(); ++k) indices.push_back(fv[k]);
            if (m.hasFVar()) {
                Far::ConstIndexArray fvv = lvl.GetFaceFVarValues(f, 0);
                for (int k = 0; k < fvv.size(); ++k) fvIdx.push_back(fvv[k]);
            }
        }
        std::vector<int32_t> rules(nv), boundary(nv), nonmanifold(nv);
        std::vector<double> vsharp(nv);
        for (int v = 0; v < nv; ++v) {
            rules[v] = (int32_t)lvl.GetVertexRule(v);
            boundary[v] = lvl.IsVertexBoundary(v) ? 1 : 0;
            nonmanifold[v] = lvl.IsVertexNonManifold(v) ? 1 : 0;
            vsharp[v] = lvl.GetVertexSharpness(v);
        }
        const int ne = lvl.GetNumEdges();
        std::vector<int32_t> edgeVerts(2 * (size_t)ne);
        std::vector<double> esharp(ne);
        for (int e = 0; e < ne; ++e) {
            Far::ConstIndexArray ev = lvl.GetEdgeVertices(e);
            edgeVerts[2 * e] = ev[0];
            edgeVerts[2 * e + 1] = ev[1];
            esharp[e] = lvl.GetEdgeSharpness(e);
        }
        out.ints(pre + "face_counts", {nf}, counts.data());
        out.ints(pre + "face_indices", {(int64_t)indices.size()}, indices.data());
        out.ints(pre + "face_holes", {nf}, holes.data());
        out.ints(pre + "vertex_rules", {nv}, rules.data());
        out.ints(pre + "vertex_boundary", {nv}, boundary.data());
        out.ints(pre + "vertex_nonmanifold", {nv}, nonmanifold.data());
        out.reals(pre + "vertex_sharpness", {nv}, vsharp.data());
        out.ints(pre + "edge_vertices", {ne, 2}, edgeVerts.data());
        out.reals(pre + "edge_sharpness", {ne}, esharp.data());
        if (m.hasFVar()) {
            out.reals(pre + "fvar_values", {lvl.GetNumFVarValues(0), m.fvarWidth}, fvar[L].data());
            out.ints(pre + "fvar_indices", {(int64_t)fvIdx.size()}, fvIdx.data());
        }
    }
    if (m.limit) {
        const int nv = refiner->GetLevel(N).GetNumVertices();
        std::vector<double> pos((size_t)nv * m.width), t1(pos.size()), t2(pos.size());
        Rows src{pts[N].data(), m.width}, dp{pos.data(), m.width}, d1{t1.data(), m.width}, d2{t2.data(), m.width};
        primvar.Limit(src, dp, d1, d2);
        out.reals("limit/points", {nv, m.width}, pos.data());
        out.reals("limit/tan1", {nv, m.width}, t1.data());
        out.reals("limit/tan2", {nv, m.width}, t2.data());
    }
    out.close();
}

// ---------------------------------------------------------------------------------------------- bench
using Clock = std::chrono::steady_clock;

double seconds(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double>(b - a).count(); }

int64_t peakRssBytes() {
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return (int64_t)ru.ru_maxrss * 1024;  // Linux reports kilobytes
}

double maxAbsDiff(const float *a, const float *b, size_t n) {
    double d = 0;
    for (size_t i = 0; i < n; ++i) d = std::max(d, (double)std::fabs(a[i] - b[i]));
    return d;
}

// Stencil entries (index, weight pairs) in use: the sum of the stencil sizes. (OpenSubdiv 3.5 can leave its
// weight vector longer than that, so GetWeights().size() over-counts; tableBytes counts the vectors as held.)
size_t tableEntries(const Far::StencilTable &t) {
    size_t n = 0;
    for (int s : t.GetSizes()) n += (size_t)s;
    return n;
}

size_t tableBytes(const Far::StencilTable &t) {
    return t.GetSizes().size() * sizeof(int) + t.GetOffsets().size() * sizeof(Far::Index) +
           t.GetControlIndices().size() * sizeof(Far::Index) + t.GetWeights().size() * sizeof(float);
}

std::string num(double v) {
    std::ostringstream s;
    s.precision(9);
    s << v;
    return s.str();
}

int bench(int argc, char **argv) {
    if (argc < 3) throw UsageError("bench needs a mesh file");
    std::string inPath = argv[2];
    int level = -1, reps = 5;
    double budgetMb = 2048;
    std::string factorized = "last";
    for (int i = 3; i < argc; ++i) {
        std::string a = argv[i];
        if (i + 1 >= argc) throw UsageError("option " + a + " needs a value");
        std::string v = argv[++i];
        if (a == "--level") level = std::atoi(v.c_str());
        else if (a == "--reps") reps = std::atoi(v.c_str());
        else if (a == "--budget-mb") budgetMb = std::atof(v.c_str());
        else if (a == "--factorized") factorized = v;
        else throw UsageError("unknown bench option " + a);
    }
    if (reps < 1) throw UsageError("--reps must be >= 1");
    if (factorized != "last" && factorized != "all") throw UsageError("--factorized must be last or all");
    MeshInput m;
    loadMesh(readRecords(inPath), m);
    if (level >= 0) m.level = level;
    if (m.level < 1 || m.level > 10) throw UsageError("bench needs a level in 1..10");
    if (m.width != 3) throw UsageError("bench needs (n, 3) points");
    const int N = m.level;
    std::ostringstream js;
    js << "{\"osd_version\": \"" << OPENSUBDIV_VERSION_MAJOR << "." << OPENSUBDIV_VERSION_MINOR << "."
       << OPENSUBDIV_VERSION_PATCH << "\", \"level\": " << N << ", \"reps\": " << reps
       << ", \"control_vertices\": " << m.numVertices << ", \"control_faces\": " << m.counts.size();

    // (a) topology
    std::unique_ptr<Far::TopologyRefiner> refiner;
    double best = 1e300;
    for (int r = 0; r < reps; ++r) {
        refiner.reset();
        auto t0 = Clock::now();
        Far::TopologyRefiner *tr = createRefiner(m);
        tr->RefineUniform(Far::TopologyRefiner::UniformOptions(N));
        auto t1 = Clock::now();
        refiner.reset(tr);
        best = std::min(best, seconds(t0, t1));
    }
    const int nvN = refiner->GetLevel(N).GetNumVertices();
    js << ", \"refined_vertices\": " << nvN << ", \"refined_faces\": " << refiner->GetLevel(N).GetNumFaces()
       << ", \"vertices_all_levels\": " << refiner->GetNumVerticesTotal();
    js << ", \"topology_s\": " << num(best);
    const int64_t rssTopology = peakRssBytes();

    // (b) table-free interpolation, float32
    std::vector<std::vector<Vec3f>> lv(N + 1);
    lv[0].resize(m.numVertices);
    for (int v = 0; v < m.numVertices; ++v)
        lv[0][v] = Vec3f{(float)m.points[3 * v], (float)m.points[3 * v + 1], (float)m.points[3 * v + 2]};
    for (int L = 1; L <= N; ++L) lv[L].resize(refiner->GetLevel(L).GetNumVertices());
    Far::PrimvarRefiner primvar(*refiner);
    double bestInterp = 1e300;
    for (int r = 0; r < reps; ++r) {
        auto t0 = Clock::now();
        for (int L = 1; L <= N; ++L) {
            Vec3f *src = lv[L - 1].data(), *dst = lv[L].data();
            primvar.Interpolate(L, src, dst);
        }
        bestInterp = std::min(bestInterp, seconds(t0, Clock::now()));
    }
    const float *reference = &lv[N][0].x;
    const int64_t rssInterpolate = peakRssBytes();

    // (c) per-level stencil tables
    std::ostringstream pl;
    {
        Far::StencilTableFactory::Options so;
        so.generateIntermediateLevels = true;
        so.factorizeIntermediateLevels = false;
        so.generateControlVerts = false;
        so.generateOffsets = true;
        so.maxLevel = N;
        std::unique_ptr<const Far::StencilTable> table;
        double bestBuild = 1e300, bestEval = 1e300;
        for (int r = 0; r < reps; ++r) {
            table.reset();
            auto t0 = Clock::now();
            const Far::StencilTable *t = Far::StencilTableFactory::Create(*refiner, so);
            bestBuild = std::min(bestBuild, seconds(t0, Clock::now()));
            table.reset(t);
        }
        std::vector<std::vector<float>> buf(N + 1);
        buf[0].resize(3 * (size_t)m.numVertices);
        for (size_t i = 0; i < buf[0].size(); ++i) buf[0][i] = (float)m.points[i];
        std::vector<int> start(N + 2, 0);
        for (int L = 1; L <= N; ++L) {
            buf[L].resize(3 * (size_t)refiner->GetLevel(L).GetNumVertices());
            start[L + 1] = start[L] + refiner->GetLevel(L).GetNumVertices();
        }
        if (start[N + 1] != table->GetNumStencils()) throw OsdError("unexpected per-level stencil count");
        Osd::BufferDescriptor desc(0, 3, 3);
        for (int r = 0; r < reps; ++r) {
            auto t0 = Clock::now();
            for (int L = 1; L <= N; ++L) {
                Osd::CpuEvaluator::EvalStencils(buf[L - 1].data(), desc, buf[L].data(), desc, table->GetSizes().data(),
                                                table->GetOffsets().data(), table->GetControlIndices().data(),
                                                table->GetWeights().data(), start[L], start[L + 1]);
            }
            bestEval = std::min(bestEval, seconds(t0, Clock::now()));
        }
        pl << "{\"options\": {\"generateIntermediateLevels\": true, \"factorizeIntermediateLevels\": false, "
              "\"generateControlVerts\": false, \"generateOffsets\": true, \"maxLevel\": "
           << N << "}, \"build_s\": " << num(bestBuild) << ", \"eval_s\": " << num(bestEval)
           << ", \"stencils\": " << table->GetNumStencils() << ", \"entries\": " << tableEntries(*table)
           << ", \"table_bytes\": " << tableBytes(*table)
           << ", \"max_abs_diff_vs_interpolate\": " << num(maxAbsDiff(buf[N].data(), reference, 3 * (size_t)nvN))
           << "}";
    }
    const int64_t rssPerLevel = peakRssBytes();

    // (d) factorised stencils
    std::ostringstream fz;
    {
        const bool all = factorized == "all";
        Far::StencilTableFactory::Options so;
        so.generateOffsets = true;
        so.generateIntermediateLevels = all;
        so.maxLevel = N;
        // memory estimate from a small factorised table
        Far::StencilTableFactory::Options sample = so;
        sample.generateIntermediateLevels = false;
        sample.maxLevel = std::min(N, 2);
        double avgSize;
        {
            std::unique_ptr<const Far::StencilTable> t(Far::StencilTableFactory::Create(*refiner, sample));
            avgSize = t->GetNumStencils() ? (double)tableEntries(*t) / t->GetNumStencils() : 0.0;
        }
        const double stencils = all ? (double)(refiner->GetNumVerticesTotal() - m.numVertices) : (double)nvN;
        const double estimate = 3.0 * (stencils * avgSize * 8.0 + stencils * 8.0);
        fz << "{\"options\": {\"generateIntermediateLevels\": " << (all ? "true" : "false")
           << ", \"factorizeIntermediateLevels\": true, \"generateControlVerts\": false, \"generateOffsets\": true, "
              "\"maxLevel\": "
           << N << "}, \"estimated_build_bytes\": " << num(estimate);
        if (estimate > budgetMb * 1048576.0) {
            fz << ", \"skipped\": true, \"budget_bytes\": " << num(budgetMb * 1048576.0) << "}";
        } else {
            std::unique_ptr<const Far::StencilTable> table;
            double bestBuild = 1e300, bestEval = 1e300;
            for (int r = 0; r < reps; ++r) {
                table.reset();
                auto t0 = Clock::now();
                const Far::StencilTable *t = Far::StencilTableFactory::Create(*refiner, so);
                bestBuild = std::min(bestBuild, seconds(t0, Clock::now()));
                table.reset(t);
            }
            std::vector<float> src(m.points.begin(), m.points.end());
            std::vector<float> dst(3 * (size_t)table->GetNumStencils());
            Osd::BufferDescriptor desc(0, 3, 3);
            for (int r = 0; r < reps; ++r) {
                auto t0 = Clock::now();
                Osd::CpuEvaluator::EvalStencils(src.data(), desc, dst.data(), desc, table->GetSizes().data(),
                                                table->GetOffsets().data(), table->GetControlIndices().data(),
                                                table->GetWeights().data(), 0, table->GetNumStencils());
                bestEval = std::min(bestEval, seconds(t0, Clock::now()));
            }
            const float *last = dst.data() + dst.size() - 3 * (size_t)nvN;  // level N comes last
            fz << ", \"skipped\": false, \"build_s\": " << num(bestBuild) << ", \"eval_s\": " << num(bestEval)
               << ", \"stencils\": " << table->GetNumStencils() << ", \"entries\": " << tableEntries(*table)
               << ", \"table_bytes\": " << tableBytes(*table)
               << ", \"max_abs_diff_vs_interpolate\": " << num(maxAbsDiff(last, reference, 3 * (size_t)nvN)) << "}";
        }
    }
    const int64_t rssFactorized = peakRssBytes();
    js << ", \"interpolate_s\": " << num(bestInterp);
    js << ", \"per_level_stencils\": " << pl.str();
    js << ", \"factorized_stencils\": " << fz.str();
    js << ", \"peak_rss_bytes_after\": {\"topology\": " << rssTopology << ", \"interpolate\": " << rssInterpolate
       << ", \"per_level_stencils\": " << rssPerLevel << ", \"factorized_stencils\": " << rssFactorized << "}";
    js << ", \"peak_rss_bytes\": " << peakRssBytes() << "}";
    std::printf("%s\n", js.str().c_str());
    return 0;
}

int usage() {
    std::fprintf(stderr,
                 "usage: osd_peer refine IN OUT [IN OUT ...]\n"
                 "       osd_peer bench IN [--level N] [--reps R] [--budget-mb M] [--factorized last|all]\n"
                 "       osd_peer version\n");
    return 2;
}

}  // namespace

int main(int argc, char **argv) {
    Far::SetErrorCallback(onOsdError);
    Far::SetWarningCallback(onOsdWarning);
    if (argc < 2) return usage();
    std::string mode = argv[1];
    try {
        if (mode == "refine") {
            if (argc < 4 || (argc - 2) % 2 != 0) return usage();
            for (int i = 2; i < argc; i += 2) {
                try {
                    refineOne(argv[i], argv[i + 1]);
                } catch (const OsdError &e) {
                    throw OsdError(std::string(argv[i]) + ": " + e.what());
                } catch (const std::exception &e) {
                    throw UsageError(std::string(argv[i]) + ": " + e.what());
                }
            }
            return 0;
        }
        if (mode == "bench") return bench(argc, argv);
        if (mode == "version") {
            std::printf("%d.%d.%d\n", OPENSUBDIV_VERSION_MAJOR, OPENSUBDIV_VERSION_MINOR, OPENSUBDIV_VERSION_PATCH);
            return 0;
        }
        return usage();
    } catch (const OsdError &e) {
        std::fprintf(stderr, "osd_peer: %s\n", e.what());
        return 1;
    } catch (const std::exception &e) {
        std::fprintf(stderr, "osd_peer: %s\n", e.what());
        return 2;
    }
}
