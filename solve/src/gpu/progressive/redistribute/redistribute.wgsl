// requires: common.wgsl, elements.wgsl, receive.wgsl, redistribute_bindings.wgsl
// Redistribution after dynamic objects move (thesis ch. 3, §4.4, §4.5). It
// receives from its shooters as progressive refinement does (receive.wgsl:
// `visibility`, `form_factor`), over the same elements (elements.wgsl).
//
// The moved set M is marked OBJECT_MOVING in `object_flags`; the static
// set C is everything else. `elements` hold the NEW positions. Shot
// radiosity is B^s = B - B^u.
//
// Entry points:
//   reset_moving         save B^s of M into `old_shot`, then reset B of M to
//                        its emission (reshooting, thesis §4.4.1, §4.5.1).
//   shooter_energy_dyn   the intermediate texture T for incremental batches.
//   gather_moving        R_g(C, M): each element of M gathers the shot
//                        radiosity of C from its front hemicube (thesis
//                        Alg. 4.5 GATHERRADIOSITY) without the emission,
//                        takes its own direct light (`moving_direct`),
//                        and fills T.
//   regather_moving      after the last batch: each tile of M gathers again,
//                        from C's total radiosity, which now holds the
//                        shadows and light M's new position casts on C
//                        (`regathered`; what the texels show, not what
//                        the tiles shot).
//   shade_back           the back hemicubes' elements shaded with their shot
//                        radiosity, for the cross projection.
//   reconstruct_dyn      every element receives the batch's redistribution:
//                        INCREMENTALRECONSTRUCTIONSHADER (Alg. 4.3) or
//                        CROSSPROJECTIONRECONSTRUCTIONSHADER (Alg. 4.5).

// Fills the shown textures for a cross batch's hemicubes: the back
// hemicubes' shot radiosity (`shade_back`) and the tiles' gathering's
// reflected shot radiosity.
@compute @workgroup_size(64)
fn shade_static(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = gid.x;
    if (e >= batch.element_count) {
        return;
    }
    let at = shown_texel(e);
    if (is_moving(elements[e])) {
        textureStore(shown_back_out, at, vec4<f32>(0.0));
        textureStore(shown_front_out, at, vec4<f32>(0.0));
        return;
    }
    let b = radiosity[e].rgb;
    let u = unshot[e].rgb;
    textureStore(shown_back_out, at, vec4<f32>(b - u + held[e].rgb, 1.0));
    // Without the emission: each texel of a tile takes its direct light on
    // its own (`moving_direct`).
    textureStore(shown_front_out, at, vec4<f32>(b - emission[e].rgb - u, 1.0));
}

// Shades the back hemicubes of a cross job (slots [0, 2 back.old_from_slot),
// every slot the job's projection reads, whether drawn now or kept from the
// last move, `run_cross` in gpu/progressive/redistribute/cross.rs): the element a
// pixel sees shows its shot radiosity (`shown_back`, just filled by
// `shade_static`), with the distance the drawing stored.
@compute @workgroup_size(8, 8)
fn shade_back(@builtin(global_invocation_id) gid: vec3<u32>) {
    let rows = 2u * back.old_from_slot * back.resolution;
    if (gid.x >= 5u * back.resolution || gid.y >= rows) {
        return;
    }
    let at = vec2<i32>(gid.xy);
    let seen = textureLoad(back_ids, at, 0).xy;
    var shaded = vec4<f32>(0.0);
    if (seen.x != NO_PATCH) {
        shaded = vec4<f32>(textureLoad(shown_back, shown_texel(seen.x), 0).rgb, bitcast<f32>(seen.y));
    }
    textureStore(back_rad_out, at, shaded);
}

// Fills the front texture for the regathering (`regather_moving`): what the
// texels show, the static set's total reflected radiosity, which holds the
// shadow and light the move cast. Negative light (what a move took back
// before it was given) is not light a surface reflects. An invalid texel
// (under geometry, a fragment beside it may still be nearest to its sample)
// keeps what redistribution hands it and never shoots it, so its total
// holds many moves' worth of changes; it gives its reflected shot
// radiosity instead.
@compute @workgroup_size(64)
fn shade_total(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = gid.x;
    if (e >= batch.element_count) {
        return;
    }
    let el = elements[e];
    let at = shown_texel(e);
    if (is_moving(el)) {
        textureStore(shown_front_out, at, vec4<f32>(0.0));
        return;
    }
    let reflected = radiosity[e].rgb - emission[e].rgb;
    var shown = max(reflected, vec3<f32>(0.0));
    if (is_invalid(el)) {
        shown = reflected - unshot[e].rgb + held[e].rgb;
    }
    textureStore(shown_front_out, at, vec4<f32>(shown, 1.0));
}

@compute @workgroup_size(64)
fn reset_moving(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = gid.x;
    if (e >= batch.element_count || !is_moving(elements[e])) {
        return;
    }
    old_shot[e] = radiosity[e] - unshot[e] - smoothed[e];
    gathered[e] = vec4<f32>(0.0);
    regathered[e] = vec4<f32>(0.0);
    smoothed[e] = vec4<f32>(0.0);
    radiosity[e] = emission[e];
    unshot[e] = select(vec4<f32>(0.0), emission[e], (batch.mode & RESET_UNSHOT) != 0u);
}

// One workgroup per shooter of an incremental batch: area-weighted averages
// over the shooter's tile (GENERATESHOOTINGPATCHES with the radiosity type
// of Alg. 4.3: negated old shot radiosity for M, shot and unshot for C).
@compute @workgroup_size(64)
fn shooter_energy_dyn(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let s = shooters[wid.x];
    let kind = batch.mode & KIND_MASK;
    let tw = s.tile.z - s.tile.x;
    let count = tw * (s.tile.w - s.tile.y);
    var first = vec3<f32>(0.0);
    var second = vec3<f32>(0.0);
    var area = 0.0;
    for (var k = lid; k < count; k += WG) {
        let idx = batch.first_element + (s.tile.y + k / tw) * batch.chart_w + s.tile.x + k % tw;
        let a = elements[idx].position.w;
        area += a;
        if (kind == KIND_NEGATIVE) {
            first -= old_shot[idx].rgb * a;
        } else {
            first += unshot[idx].rgb * a;
            second += (radiosity[idx].rgb - unshot[idx].rgb) * a;
            unshot[idx] = vec4<f32>(0.0);
        }
    }
    partial[lid] = first;
    partial_power[lid] = area;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial[lid] += partial[lid + stride];
            partial_power[lid] += partial_power[lid + stride];
        }
        workgroupBarrier();
    }
    let total_area = max(partial_power[0], 1e-30);
    if (lid == 0u) {
        energy[wid.x] = vec4<f32>(partial[0] / total_area, 0.0);
    }
    workgroupBarrier();
    partial[lid] = second;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial[lid] += partial[lid + stride];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        energy[batch.shooters + wid.x] = vec4<f32>(partial[0] / total_area, 0.0);
    }
}

// Delta form factor of hemicube pixel `px` of `face` (thesis §2.2.2): the
// top face weighs a pixel at (x, y, 1) by 1/(π (x²+y²+1)²), a side face at
// (x, y, 1) with y towards the normal by y/(π (x²+y²+1)²), zero below the
// horizon; dA = (2/res)².
fn delta_form_factor(face: u32, px: vec2<u32>, res: u32) -> f32 {
    let r = f32(res);
    let x = (f32(px.x) + 0.5) / r * 2.0 - 1.0;
    let y = 1.0 - (f32(px.y) + 0.5) / r * 2.0;
    let d = x * x + y * y + 1.0;
    let da = 4.0 / (r * r);
    if (face == 0u) {
        return da / (PI * d * d);
    }
    return max(y, 0.0) * da / (PI * d * d);
}

// The irradiance the front hemicube of slot `k` sees (zero unless
// `present`): the workgroup's sum over its pixels of what the element each
// sees shows (`shown_front`, as `shade_static` or `shade_total` last wrote
// it) by their delta form factors. Call from uniform control flow.
fn front_irradiance(k: u32, lid: u32, present: bool) -> vec3<f32> {
    let res = GATHER_RESOLUTION;
    var acc = vec3<f32>(0.0);
    if (present) {
        let per_face = res * res;
        for (var p = lid; p < 5u * per_face; p += WG) {
            let face = p / per_face;
            let q = p % per_face;
            let px = vec2<u32>(q % res, q / res);
            let texel = vec2<i32>(i32(face * res + px.x), i32(k * res + px.y));
            let seen = textureLoad(front_ids, texel, 0).r;
            if (seen != NO_PATCH) {
                acc += textureLoad(shown_front, shown_texel(seen), 0).rgb * delta_form_factor(face, px, res);
            }
        }
    }
    partial[lid] = acc;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial[lid] += partial[lid + stride];
        }
        workgroupBarrier();
    }
    let h = partial[0];
    workgroupBarrier();
    return h;
}

// After the last batch of a move, one workgroup per tile of M at its new
// position (slot k's shooter as in `gather_moving`): H seen in the front
// hemicube of C's total radiosity (`shade_total`), recorded for
// every texel of the tile. `gather_moving` gathered C's shot radiosity
// B^s, which the cross projection must use (thesis §4.5.2) but which
// lacks what M's new position changes on C: the shadow M casts on the
// floor beside it, the light it reflects onto the walls. A face that sees
// the floor around it read 10-30% too bright from B^s (cornell-large, a
// box moved 0.5 m); the total radiosity B holds those changes once every
// batch has run. What the tiles shot stays what they gathered first, so
// the next move's take-back is unchanged (`smooth_moving`).
@compute @workgroup_size(64)
fn regather_moving(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let k = wid.x;
    let s = shooters[k];
    let h = front_irradiance(k, lid, true);
    let first_element = bitcast<u32>(s.eye.w);
    let chart_w = bitcast<u32>(s.su.w);
    let tw = s.tile.z - s.tile.x;
    let count = tw * (s.tile.w - s.tile.y);
    for (var t = lid; t < count; t += WG) {
        let e = first_element + (s.tile.y + t / tw) * chart_w + s.tile.x + t % tw;
        regathered[e] = vec4<f32>(h, 1.0);
    }
}

// One workgroup per tile of M (one shooter each; eye.w holds the bitcast
// first element of the tile's patch and su.w its chart width): gather the
// shot radiosity of C seen from the tile's new position (thesis Alg. 4.5
// lines 23-27) and record it for every texel of the tile (`gathered`; the
// texels receive B += ρ H once every tile has gathered, interpolated
// between tile centres by `smooth_moving`, so that a face does not show
// its tiles as bands); the tile's average uses its own H; clear their
// unshot radiosity, since the tile shoots everything (Alg. 4.4 lines
// 13-14); and fill T with the tile's area-weighted new total radiosity and
// negated old shot radiosity (Alg. 4.4 line 4, GENERATESHOOTINGPATCHES with
// the "shot" type).
@compute @workgroup_size(64)
fn gather_moving(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lid: u32) {
    let k = wid.x;
    let s = shooters[k];
    let has_new = (batch.mode & HAS_NEW) != 0u;
    let has_old = (batch.mode & HAS_OLD) != 0u;
    let h = front_irradiance(k, lid, has_new);

    let first_element = bitcast<u32>(s.eye.w);
    let chart_w = bitcast<u32>(s.su.w);
    let tw = s.tile.z - s.tile.x;
    let count = tw * (s.tile.w - s.tile.y);
    var total = vec3<f32>(0.0);
    var old = vec3<f32>(0.0);
    var area = 0.0;
    for (var t = lid; t < count; t += WG) {
        let e = first_element + (s.tile.y + t / tw) * chart_w + s.tile.x + t % tw;
        // Weights for the tile's averages: object-space areas. The placed
        // areas would do for a move, but a removal places M nowhere (its
        // matrix is zero, so are its placed areas) and its negated old shot
        // radiosity would average to nothing: removals would keep adding
        // the light M had blocked without taking back what M had shot.
        // All texels of a tile share one scale, so the averages are the same.
        let a = local_elements[e].position.w;
        area += a;
        if (has_new) {
            gathered[e] = vec4<f32>(h, 1.0);
            unshot[e] = vec4<f32>(0.0);
            total += (radiosity[e].rgb + elements[e].albedo.rgb * (h + moving_direct[e].rgb)) * a;
        }
        if (has_old) {
            old += old_shot[e].rgb * a;
        }
    }
    partial[lid] = total;
    partial_power[lid] = area;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial[lid] += partial[lid + stride];
            partial_power[lid] += partial_power[lid + stride];
        }
        workgroupBarrier();
    }
    let total_area = max(partial_power[0], 1e-30);
    if (lid == 0u) {
        energy[k] = vec4<f32>(partial[0] / total_area, 0.0);
    }
    workgroupBarrier();
    partial[lid] = old;
    workgroupBarrier();
    for (var stride = WG / 2u; stride > 0u; stride = stride / 2u) {
        if (lid < stride) {
            partial[lid] += partial[lid + stride];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        energy[batch.shooters + k] = vec4<f32>(-partial[0] / total_area, 0.0);
    }
}

// Shot radiosity of the static set seen through back hemicube `slot` in
// world direction `d` from its eye (bilinear; clamped inside the drawn part
// of the face — a side face's upper half, gpu/hemicube.rs `face_height` —
// so that neighbouring faces and undrawn rows do not bleed in), and in .a
// the distance.
fn sample_back(slot: u32, b: Shooter, d: vec3<f32>) -> vec4<f32> {
    let at = back_pixel(slot, b, d);
    if (at.z <= 0.0) {
        return vec4<f32>(0.0);
    }
    let size = vec2<f32>(textureDimensions(back_rad));
    return textureSampleLevel(back_rad, back_sampler, at.xy / size, 0.0);
}

// Where world direction `d` from back hemicube `slot`'s eye lands in the
// back target (xy, pixels, clamped as `sample_back` says), and z > 0 if
// it lies in front of the face it falls in.
fn back_pixel(slot: u32, b: Shooter, d: vec3<f32>) -> vec3<f32> {
    let face = face_of(b, d);
    let l = face_local(b, face, d);
    let res = f32(back.resolution);
    let ndc = l.xy / max(l.z, 1e-30);
    let rows = select(ceil(res * 0.5), res, face == 0u);
    let p = clamp(vec2<f32>((ndc.x * 0.5 + 0.5) * res, (0.5 - ndc.y * 0.5) * res), vec2<f32>(0.5), vec2<f32>(res - 0.5, rows - 0.5));
    return vec3<f32>(vec2<f32>(f32(face) * res, f32(slot) * res) + p, l.z);
}

// The distance the back hemicube `slot` stores in direction `d` (its
// nearest pixel: a depth read between two surfaces would be neither's).
fn back_depth(slot: u32, b: Shooter, d: vec3<f32>) -> f32 {
    let at = back_pixel(slot, b, d);
    if (at.z <= 0.0) {
        return 0.0;
    }
    return textureLoad(back_rad, vec2<i32>(at.xy), 0).a;
}

// Cell `c` (row by row) of a g x g grid on shooter `b`: in xyz the
// centroid of the cell's part on the shooter's region (world), in w that
// part's share of the cell (0 for a cell wholly above a triangle's
// diagonal). Computed per receiver from the shooter, which lives in a
// uniform buffer: on lavapipe a storage-buffer read is a per-lane loop,
// and reading a precomputed grid cost more than placing it again.
fn grid_cell(b: Shooter, c: u32, g: u32) -> vec4<f32> {
    let ij = vec2<f32>(f32(c % g), f32(c / g));
    let lo = ij / f32(g);
    let hi = (ij + 1.0) / f32(g);
    var part = vec3<f32>(1.0, (lo + hi) * 0.5);
    let cut = shooter_cut(b);
    if (is_cut(cut)) {
        part = cut_cell(lo, hi, cut);
    }
    return vec4<f32>(b.corner.xyz + b.su.xyz * part.y + b.sv.xyz * part.z, part.x);
}

// P(C, j, i) of thesis eq. 3.3.2 by the non-incremental cross projection
// (thesis §4.5.2, Alg. 4.5 PROJECTEDRADIOSITY and REPROJECT): rays from the
// receiver `x` through a CROSS_GRID² grid on the shooter in `slot` sample
// the back hemicube of shot radiosity; each ray's direction is corrected
// for the hemicube's different origin with the depth found along a
// parallel ray. A shooter cut by a triangle's diagonal casts rays through
// the part of each grid cell on the triangle, weighted by its share
// (`grid_cell`).
// `coarse`: through the coarse grid instead (a receiver that sees the
// tile small, `CROSS_COARSE_BELOW`).
fn projected_radiosity(slot: u32, x: vec3<f32>, coarse: bool) -> vec3<f32> {
    let b = back_shooters[slot];
    var acc = vec3<f32>(0.0);
    var weight = 0.0;
    let g = select(CROSS_GRID, coarse_grid(), coarse);
    for (var c = 0u; c < g * g; c++) {
        let cell = grid_cell(b, c, g);
        if (cell.w <= 0.0) {
            continue;
        }
        weight += cell.w;
        let r = normalize(cell.xyz - x);
        let depth = back_depth(slot, b, r);
        // Nothing there (distance 0 is the cleared background): the
        // ray leaves the scene (an open side) and carried no light to
        // block. Reprojecting it by distance 0 would sample the
        // direction of the cell itself, nearly in the patch's plane,
        // and take away light that never passed.
        if (depth <= 0.0) {
            continue;
        }
        let p = cell.xyz + r * depth;
        acc += cell.w * sample_back(slot, b, p - b.eye.xyz).rgb;
    }
    return acc / max(weight, 1e-12);
}

// The slots `first .. first + len` of a cross batch (`n` tiles, sides
// shifted by `side_shift`) that reach element `id` at `x` (visibility
// looked up from `d`), bit b for slot first + b: those of a pose that
// exists, that the element may receive from (a moving element only from
// the new pose's fronts, R_p(M, M)), not its own patch, with the element
// in front of the tile and visible from it.
fn mark_slots(first: u32, len: u32, n: u32, side_shift: u32, has_new: bool, has_old: bool, moving: bool, id: u32, x: vec3<f32>, d: vec3<f32>) -> u32 {
    var marked = 0u;
    for (var b = 0u; b < len; b++) {
        let q = first + b;
        let side = (q / n) << side_shift;
        let new_pose = side < 2u;
        let front = (side & 1u) == 0u;
        if ((new_pose && !has_new) || (!new_pose && !has_old)) {
            continue;
        }
        if (moving && !(new_pose && front)) {
            continue;
        }
        let s = shooters[q];
        if (bitcast<u32>(s.n.w) == id || dot(x - s.corner.xyz, s.n.xyz) <= 0.0) {
            continue;
        }
        if (visibility(q, s, d - s.eye.xyz, x, id) > 0.0) {
            marked |= 1u << b;
        }
    }
    return marked;
}

// One thread per element: what this batch redistributes to it.
@compute @workgroup_size(64)
fn reconstruct_dyn(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = gid.x;
    if (e >= batch.element_count) {
        return;
    }
    let el = elements[e];
    if (absent(el)) {
        return;
    }
    let id = bitcast<u32>(el.normal.w);
    let moving = is_moving(el);
    let kind = batch.mode & KIND_MASK;
    let n = batch.shooters;
    let x = el.position.xyz;
    let nx = el.normal.xyz;
    let d = el.lookup.xyz;
    var h = vec3<f32>(0.0);
    if (kind == KIND_NEGATIVE) {
        // R_p(M, C), first part: -B^s_M with the old form factors.
        if (moving) {
            return;
        }
        for (var k = 0u; k < n; k++) {
            let s = shooters[k];
            if (dot(x - s.corner.xyz, s.n.xyz) > 0.0) {
                let v = visibility(k, s, d - s.eye.xyz, x, id);
                if (v > 0.0) {
                    h += energy[k].rgb * (v * form_factor(s, x, nx));
                }
            }
        }
    } else if (kind == KIND_STATIC) {
        if (id == batch.patch_id) {
            return;
        }
        for (var k = 0u; k < n; k++) {
            let s = shooters[k];
            if (dot(x - s.corner.xyz, s.n.xyz) <= 0.0) {
                continue;
            }
            let dir = d - s.eye.xyz;
            let seen_new = visibility(k, s, dir, x, id);
            var r = vec3<f32>(0.0);
            if (moving) {
                // R_p(C, M) by reshooting: the total radiosity (eq. 4.4.1).
                r = seen_new * (energy[k].rgb + energy[n + k].rgb);
            } else {
                // R_p(C, C): the four visibility cases of Alg. 4.3 lines
                // 25-33 (seen at both poses: B^u; only at the new: B^u +
                // B^s; only at the old: -B^s; neither: nothing), written
                // for fractional visibility.
                let seen_old = visibility(n + k, s, dir, x, id);
                r = seen_new * (energy[k].rgb + energy[n + k].rgb) - seen_old * energy[n + k].rgb;
            }
            if (all(r == vec3<f32>(0.0))) {
                continue;
            }
            h += r * form_factor(s, x, nx);
        }
    } else if (kind == KIND_CROSS) {
        // Slots: [0, n) new front, [n, 2n) new back, [2n, 3n) old front,
        // [3n, 4n) old back hemicubes of the same n moving elements (with
        // ONE_SIDED: [0, n) new front, [n, 2n) old front; `side` below is
        // the same either way). Marked MARK_CHUNK at a time: about half
        // fail, since an element lies in front of either a tile's front or
        // its back hemicube.
        let has_new = (batch.mode & HAS_NEW) != 0u;
        let has_old = (batch.mode & HAS_OLD) != 0u;
        let side_shift = select(0u, 1u, (batch.mode & ONE_SIDED) != 0u);
        let slots = (4u >> side_shift) * n;
        let half = slots / 2u;
        // The last job's marks, read before this job's new half replaces
        // them (a moving element receives from no old slot).
        var kept = array<u32, MARK_WORDS>();
        let kept_marks = (batch.mode & KEPT_MARKS) != 0u;
        if (kept_marks && has_old && !moving) {
            for (var w = 0u; w < MARK_WORDS; w++) {
                kept[w] = marks[e * MARK_WORDS + w];
            }
        }
        // Chunks never straddle the two poses' halves.
        var first = 0u;
        loop {
            if (first >= slots) {
                break;
            }
            let old_half = first >= half;
            let len = min(MARK_CHUNK, select(half, slots, old_half) - first);
            let word = (first - select(0u, half, old_half)) / MARK_CHUNK;
            var marked = 0u;
            if (old_half && kept_marks) {
                marked = kept[word];
            } else {
                marked = mark_slots(first, len, n, side_shift, has_new, has_old, moving, id, x, d);
                if (!old_half) {
                    marks[e * MARK_WORDS + word] = marked;
                }
            }
            let base = first;
            first += len;
            while (marked != 0u) {
                let q = base + next_marked(&marked);
                let side = (q / n) << side_shift;
                let k = q % n;
                let new_pose = side < 2u;
                let front = (side & 1u) == 0u;
                let s = shooters[q];
                let ff = form_factor(s, x, nx);
                var r = vec3<f32>(0.0);
                if (new_pose && front) {
                    // R_p(M, C) and R_p(M, M) with the new total radiosity.
                    r = energy[k].rgb;
                } else if (front) {
                    // -B^s_j with the old form factor (R_p(M, C)).
                    r = energy[n + k].rgb;
                }
                if (!moving) {
                    // R_x(C, C), eq. 3.3.1: -P(C, j', i) for the light the
                    // new position blocks, +P(C, j, i) for what the old one
                    // no longer blocks; from either side of the patch.
                    let p = projected_radiosity(q, x, ff < CROSS_COARSE_BELOW);
                    r += select(p, -p, new_pose);
                }
                // Visibility is 0 or 1: a marked slot sees x.
                h += r * ff;
            }
        }
    }
    if (any(h != vec3<f32>(0.0))) {
        let db = vec4<f32>(el.albedo.rgb * h, 0.0);
        radiosity[e] += db;
        unshot[e] += db;
    }
}

// The cross tiling of an axis of `n` texels (`begin_move`): `tile_count(n)`
// tiles, tile i covering texels [i n / g, (i + 1) n / g).
fn tile_count(n: u32) -> u32 {
    return max((n + CROSS_TILE - 1u) / CROSS_TILE, min(n, 2u));
}

fn tile_centre(i: u32, n: u32, g: u32) -> f32 {
    return 0.5 * (f32(i * n / g) + f32((i + 1u) * n / g) - 1.0);
}

// The tile of texel `x` along an axis.
fn tile_index(x: u32, n: u32, g: u32) -> u32 {
    var i = min(x * g / n, g - 1u);
    loop {
        if (i + 1u < g && (i + 1u) * n / g <= x) { i += 1u; } else { break; }
    }
    loop {
        if (i > 0u && i * n / g > x) { i -= 1u; } else { break; }
    }
    return i;
}

// The tiles texel `x` is interpolated between along an axis: the lower one
// and the weight of the next (0 beyond the outermost centres, which keep
// their tile's value).
fn tile_lerp(x: u32, n: u32, g: u32) -> vec2<f32> {
    let i = tile_index(x, n, g);
    let c = tile_centre(i, n, g);
    let fx = f32(x);
    if (fx < c && i > 0u) {
        let c0 = tile_centre(i - 1u, n, g);
        return vec2<f32>(f32(i - 1u), (fx - c0) / (c - c0));
    }
    if (fx > c && i + 1u < g) {
        return vec2<f32>(f32(i), (fx - c) / (tile_centre(i + 1u, n, g) - c));
    }
    return vec2<f32>(f32(i), 0.0);
}

// The irradiance of the tile (i, j) of a patch (`tile_value`; any of its
// texels holds it) in .rgb, and in .w at least 1 if the tile gathered (a tile of a
// triangle's chart wholly above its diagonal stands for no surface and
// never does, `begin_move`).
fn tile_h(range: PatchRange, g: vec2<u32>, i: u32, j: u32) -> vec4<f32> {
    return tile_value(range.first + (j * range.h / g.y) * range.w + i * range.w / g.x);
}

// What element `e`'s tile gathered: again from the total radiosity once
// `regather_moving` has run, else the first time.
fn tile_value(e: u32) -> vec4<f32> {
    let again = regathered[e];
    if (again.w > 0.5) {
        return again;
    }
    return gathered[e];
}

// H at texel (x, y) of a patch, bilinear between the centres of the tiles
// that gathered (`own`, the texel's tile's H, if none of them weighs).
fn interpolated_h(range: PatchRange, g: vec2<u32>, x: u32, y: u32, own: vec3<f32>) -> vec3<f32> {
    let lx = tile_lerp(x, range.w, g.x);
    let ly = tile_lerp(y, range.h, g.y);
    let i0 = u32(lx.x);
    let j0 = u32(ly.x);
    let i1 = min(i0 + 1u, g.x - 1u);
    let j1 = min(j0 + 1u, g.y - 1u);
    let h00 = tile_h(range, g, i0, j0);
    let h10 = tile_h(range, g, i1, j0);
    let h01 = tile_h(range, g, i0, j1);
    let h11 = tile_h(range, g, i1, j1);
    let w00 = (1.0 - lx.y) * (1.0 - ly.y) * step(0.5, h00.w);
    let w10 = lx.y * (1.0 - ly.y) * step(0.5, h10.w);
    let w01 = (1.0 - lx.y) * ly.y * step(0.5, h01.w);
    let w11 = lx.y * ly.y * step(0.5, h11.w);
    let total = w00 + w10 + w01 + w11;
    if (total <= 0.0) {
        return own;
    }
    return (h00.rgb * w00 + h10.rgb * w10 + h01.rgb * w01 + h11.rgb * w11) / total;
}

// After the last cross batch of a move, and again after `regather_moving`,
// per element of M that gathered: B += ρ H with H the tiles' irradiance
// (`tile_value`),
// interpolated bilinearly between the centres of the tiles around the
// texel on its chart. Every tile's H is the value of a point (its
// hemicube eye) standing for the tile (thesis Alg. 4.5 gathers once per
// reduced element), so reading it as samples at tile centres rather than
// as a constant per tile is the same data without the steps. What the
// tile shot (`energy`) is its constant first-gathered H, so the
// difference is kept in `smoothed` and left out of what the next move
// takes back: otherwise every move would leave a little light behind (or
// take too much).
@compute @workgroup_size(64)
fn smooth_moving(@builtin(global_invocation_id) gid: vec3<u32>) {
    let e = gid.x;
    if (e >= batch.element_count || !is_moving(elements[e])) {
        return;
    }
    let first = gathered[e];
    if (first.w < 0.5) {
        return;
    }
    let range = patches[bitcast<u32>(elements[e].normal.w)];
    let local = e - range.first;
    let g = vec2<u32>(tile_count(range.w), tile_count(range.h));
    let h = interpolated_h(range, g, local % range.w, local / range.w, tile_value(e).rgb);
    var extra = elements[e].albedo.rgb * (h - first.rgb);
    let own = moving_direct[e];
    if (first.w > 1.5 && own.w > 0.5) {
        // A texel at a contact gathered on its own (regather.rs,
        // `gather_contacts`): it shows that where it is below the tiles'
        // value, the rest kept apart as below.
        let kept = radiosity[e].rgb - smoothed[e].rgb;
        extra = min(own.rgb, kept + extra) - kept;
    }
    if (first.w > 1.5) {
        // Smoothed before (from the first gather): replace what that added
        // beyond the tile's constant.
        radiosity[e] += vec4<f32>(extra - smoothed[e].rgb, 0.0);
    } else {
        let constant = first.rgb + moving_direct[e].rgb;
        radiosity[e] += vec4<f32>(elements[e].albedo.rgb * constant + extra, 0.0);
        gathered[e].w = 2.0;
    }
    smoothed[e] = vec4<f32>(extra, 0.0);
}
