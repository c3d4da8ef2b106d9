"""Refine a person mask with OpenCV GrabCut seeded by the segmenter's mask and the body keypoints.

Runs inside the detector's interpreter (imports only numpy and cv2; no project imports). The segmenter's
soft mask gives sure foreground (confident, eroded), sure background (confidently empty and far from
the person) and probable labels in between; the visible keypoints' skeleton is painted as sure
foreground, so a light skirt on a light background that the segmenter bit into is grown back from the
colours of the rest of the person. The refinement only adds pixels, and only near the lower body (the
hull of hips, knees and ankles, grown; where skirts, dresses and coats are): elsewhere the segmenter is
better than a colour model (dark hair against a dark background, the gap under an arm), measured on the
synthetic clip where unrestricted GrabCut lowered the mask's IoU with the truth from 0.963 to 0.924.
``refine_mask`` returns the raw mask unchanged when GrabCut's answer
disagrees wildly with it (IoU below ``min_agreement``) or fails.
"""

from __future__ import annotations

import numpy as np

# skeleton segments over mediapipe's 33 landmarks painted as sure foreground
BONES = ((11, 12), (11, 13), (13, 15), (12, 14), (14, 16), (11, 23), (12, 24), (23, 24), (23, 25), (25, 27),
         (24, 26), (26, 28), (0, 11), (0, 12))


def refine_mask(image: np.ndarray, soft: np.ndarray, keypoints: np.ndarray | None, visibility: np.ndarray | None,
                *, iterations: int = 3, min_agreement: float = 0.7) -> tuple[np.ndarray, dict]:
    """image (H,W,3) uint8 RGB, soft (H,W) float in [0,1], keypoints (33,2) pixels or None, visibility (33,)
    -> (mask (H,W) float32 in [0,1], info {"used": bool, "iou_with_raw": float, "reason": str})."""
    import cv2

    H, W = soft.shape
    raw = soft > 0.5
    area = int(raw.sum())
    if area < 50:
        return soft.astype(np.float32), {"used": False, "iou_with_raw": 1.0, "reason": "mask too small"}
    ys, xs = np.nonzero(raw)
    size = max(ys.max() - ys.min(), xs.max() - xs.min(), 8)
    r = max(1, int(round(0.02 * size)))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    sure_fg = cv2.erode((soft > 0.9).astype(np.uint8), kernel) > 0
    g = max(2, int(0.1 * size))  # beyond a tenth of the person's size from the mask: surely background
    far = ~grow(raw, g)
    zone = _lower_body_zone(keypoints, visibility, (H, W), size)
    labels = np.where(soft > 0.5, cv2.GC_PR_FGD, cv2.GC_BGD).astype(np.uint8)
    labels[(soft <= 0.5) & zone & ~far] = cv2.GC_PR_BGD
    labels[sure_fg] = cv2.GC_FGD
    if keypoints is not None and visibility is not None:
        skel = np.zeros((H, W), np.uint8)
        for a, b in BONES:
            if visibility[a] >= 0.5 and visibility[b] >= 0.5:
                pa = tuple(int(v) for v in np.round(keypoints[a]))
                pb = tuple(int(v) for v in np.round(keypoints[b]))
                cv2.line(skel, pa, pb, 1, thickness=max(1, r))
        labels[(skel > 0) & ~far] = cv2.GC_FGD
    if not (labels == cv2.GC_BGD).any() and not (labels == cv2.GC_PR_BGD).any():
        return soft.astype(np.float32), {"used": False, "iou_with_raw": 1.0, "reason": "no background"}
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)  # GrabCut's and k-means' starts draw from OpenCV's global generator: same frame, same mask
    try:
        bgr = np.ascontiguousarray(image[..., ::-1])
        cv2.grabCut(bgr, labels, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    except cv2.error as exc:
        return soft.astype(np.float32), {"used": False, "iou_with_raw": 1.0, "reason": f"grabcut failed: {exc}"}
    grown = ((labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)) & zone & ~raw
    grown &= _clearly_person(image, raw, zone, far, grown)
    refined = raw | grown
    # keep the added pixels connected to the person only
    n, comp = cv2.connectedComponents(refined.astype(np.uint8))
    keep = np.unique(comp[raw])
    refined = np.isin(comp, keep[keep > 0]) | raw
    union = (refined | raw).sum()
    iou = float((refined & raw).sum() / union) if union else 1.0
    if iou < min_agreement:
        return soft.astype(np.float32), {"used": False, "iou_with_raw": iou,
                                         "reason": f"GrabCut disagrees with the segmenter (IoU {iou:.2f})"}
    out = soft.astype(np.float32).copy()
    out[refined & ~raw] = 1.0
    return out, {"used": True, "iou_with_raw": iou, "reason": ""}


def _clearly_person(image: np.ndarray, raw: np.ndarray, zone: np.ndarray, far: np.ndarray,
                    grown: np.ndarray, k: int = 6, ratio: float = 0.5) -> np.ndarray:
    """Added pixels whose colour is much nearer the person's colours in the zone than the background's
    (distance to the nearest of ``k`` colour centres, nearer by ``ratio``): where the two overlap (dark
    trousers on a dark background) GrabCut's choice is a guess and is not taken."""
    import cv2

    fg = image[raw & zone].astype(np.float32)
    bg = image[~raw & ~grown & ~far].astype(np.float32)
    if len(fg) < k or len(bg) < k or not grown.any():
        return np.zeros(raw.shape, bool)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 1.0)
    rng = np.random.default_rng(0)

    def centres(x):
        x = x[rng.choice(len(x), size=min(len(x), 4000), replace=False)]
        return cv2.kmeans(x, k, None, crit, 2, cv2.KMEANS_PP_CENTERS)[2]

    cf, cb = centres(fg), centres(bg)
    px = image[grown].astype(np.float32)
    df = np.linalg.norm(px[:, None] - cf[None], axis=-1).min(1)
    db = np.linalg.norm(px[:, None] - cb[None], axis=-1).min(1)
    out = np.zeros(raw.shape, bool)
    out[grown] = df < ratio * db
    return out


def _lower_body_zone(keypoints, visibility, shape, size) -> np.ndarray:
    """Where the refinement may add pixels: the hull of the visible hips, knees, ankles and heels, grown
    by a fifth of the person's size (a flared skirt reaches well beyond the legs)."""
    import cv2

    H, W = shape
    zone = np.zeros((H, W), np.uint8)
    if keypoints is None or visibility is None:
        return zone > 0
    ids = [23, 24, 25, 26, 27, 28, 29, 30]
    pts = np.array([keypoints[i] for i in ids if visibility[i] >= 0.3], np.float32)
    if len(pts) < 3:
        return zone > 0
    hull = cv2.convexHull(pts.reshape(-1, 1, 2)).astype(np.int32)
    cv2.fillConvexPoly(zone, hull, 1)
    return grow(zone > 0, max(1, int(0.2 * size)))


def grow(mask: np.ndarray, radius: float) -> np.ndarray:
    """``mask`` grown by a disc of ``radius`` pixels: the pixels within ``radius`` of it (exact
    Euclidean distance). Equal to a dilation by an elliptical kernel but linear in the image's size
    whatever the radius: the grown zones here reach 0.1-0.2 of the person's height, and on a 768 px
    frame the two dilations by kernels of that size took 0.74 s, more than GrabCut itself (0.59 s)."""
    import cv2

    if not mask.any():
        return np.zeros(mask.shape, bool)
    outside = np.ascontiguousarray(~mask, np.uint8)
    # float32 distances: a pixel exactly at the radius (7.0 read as 7.0000005) counts as within it
    return cv2.distanceTransform(outside, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) <= radius + 1e-3
