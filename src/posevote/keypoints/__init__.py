"""The keypoint step (beyond the paper): the object's texture tells its sides apart and
reads its viewpoint between the training views.

The edge votes see printed letters, labels and logos as edges among others;
local keypoint features (OpenCV's SIFT) match them to the training views
under a geometric check. One home: what training keeps of each view
(:mod:`~posevote.keypoints.model`) and the step that checks and refines the
best mode (:mod:`~posevote.keypoints.refine`), switched by
:attr:`~posevote.refinement.RefineOptions.keypoints`.
"""
