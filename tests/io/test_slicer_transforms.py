"""Slicer/ITK linear transform files read as rigid registrations: Slicer's own files, the forum's
test vector, every rigid ITK type against SimpleITK, and what is not a rigid linear transform."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import make_transform
from spacecal.io.slicer import read_slicer_rigid_transform, read_slicer_transform, write_slicer_transform

DATA = Path(__file__).parent / "data"
LPS = np.diag([-1.0, -1.0, 1.0, 1.0])
TRACKER_FROM_IMAGE = make_transform(
    Rotation.from_rotvec([0.4, -0.9, 1.7]).as_matrix(), [35.0, -220.0, -1380.0]
)


def _to_parent(itk):
    """Slicer's "To parent" (RAS) of an ITK resampling matrix (LPS): L inv(F) L."""
    return np.linalg.inv(LPS @ itk @ LPS)


def test_slicers_rigid3d_file_reads():
    # Modules/CLI/ResampleDTIVolume/Data/Input/rotation.tfm: 30 degrees about x, type Rigid3DTransform
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    itk = np.eye(4)
    itk[1:3, 1:3] = [[c, -s], [s, c]]
    assert np.allclose(read_slicer_rigid_transform(DATA / "slicer_rotation.tfm"), _to_parent(itk), atol=1e-15)


def test_slicers_affine_file_reads_with_its_translation():
    itk = np.eye(4)
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    itk[1:3, 1:3] = [[c, -s], [s, c]]
    itk[:3, 3] = [0.0, 2.38406, -1.41421]
    assert np.allclose(read_slicer_transform(DATA / "slicer_affine.tfm"), _to_parent(itk), atol=1e-15)


def test_a_file_of_two_transforms_is_refused():
    with pytest.raises(InvalidInputError, match="holds 2 transforms.*harden"):
        read_slicer_transform(DATA / "slicer_rotationAndAffine.tfm")


def test_the_forum_vector_reads_as_the_matrix_slicer_displayed():
    displayed = np.array(
        [[-0.12, -0.96, 0.26, 710], [0.99, -0.10, 0.10, 19], [-0.07, 0.27, 0.96, -58], [0, 0, 0, 1]]
    )
    read = read_slicer_transform(DATA / "slicer_forum_topic_270.tfm")
    assert np.allclose(read[:3, :3], displayed[:3, :3], atol=0.005)  # the display's two decimals
    assert np.allclose(read[:3, 3], displayed[:3, 3], atol=0.5)  # shown as whole millimetres
    # its matrix is the inverse of those two-decimal numbers (off a rotation by 4e-3): not a pose
    with pytest.raises(InvalidInputError, match="not rigid"):
        read_slicer_rigid_transform(DATA / "slicer_forum_topic_270.tfm")


def test_what_we_write_reads_back_exactly(tmp_path):
    path = write_slicer_transform(TRACKER_FROM_IMAGE, tmp_path / "ImageToTracker.tfm")
    assert np.allclose(read_slicer_rigid_transform(path), TRACKER_FROM_IMAGE, atol=1e-12, rtol=0)


def test_a_scaled_transform_is_refused_in_one_line(tmp_path):
    path = tmp_path / "scaled.tfm"
    path.write_text(
        "#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n"
        "Parameters: 1.02 0 0 0 1.02 0 0 0 1.02 1 2 3\nFixedParameters: 0 0 0\n"
    )
    with pytest.raises(InvalidInputError, match="not rigid") as caught:
        read_slicer_rigid_transform(path)
    assert "\n" not in str(caught.value)
    assert np.allclose(read_slicer_transform(path)[:3, :3], np.eye(3) / 1.02)  # the affine reader keeps it


def _itk_of(transform):
    origin = np.array(transform.TransformPoint((0.0, 0.0, 0.0)))
    matrix = np.eye(4)
    for axis in range(3):
        unit = [0.0, 0.0, 0.0]
        unit[axis] = 1.0
        matrix[:3, axis] = np.array(transform.TransformPoint(unit)) - origin
    matrix[:3, 3] = origin
    return matrix


def _rigid_transforms(sitk):
    euler = sitk.Euler3DTransform((5.0, -3.0, 2.0), 0.3, -0.2, 0.7, (10.0, 20.0, 30.0))
    euler_zyx = sitk.Euler3DTransform((5.0, -3.0, 2.0), 0.3, -0.2, 0.7, (10.0, 20.0, 30.0))
    euler_zyx.SetComputeZYX(True)
    versor = sitk.VersorRigid3DTransform(
        (0.1, 0.2, -0.3, np.sqrt(0.86)), (1.0, 2.0, 3.0), (40.0, -50.0, 60.0)
    )
    return {"euler": euler, "euler_zyx": euler_zyx, "versor": versor}


@pytest.mark.parametrize("suffix", [".tfm", ".txt", ".h5"])
@pytest.mark.parametrize("kind", ["euler", "euler_zyx", "versor"])
def test_every_rigid_itk_type_reads_as_simpleitk_applies_it(tmp_path, kind, suffix):
    sitk = pytest.importorskip("SimpleITK")
    transform = _rigid_transforms(sitk)[kind]
    path = tmp_path / f"t{suffix}"
    sitk.WriteTransform(transform, str(path))
    assert np.allclose(read_slicer_rigid_transform(path), _to_parent(_itk_of(transform)), atol=1e-12)


def test_a_nonlinear_h5_is_refused(tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    image = sitk.Image([4, 4, 4], sitk.sitkFloat32)
    bspline = sitk.BSplineTransformInitializer(image, [2, 2, 2])
    path = tmp_path / "warp.h5"
    sitk.WriteTransform(bspline, str(path))
    with pytest.raises(InvalidInputError, match="not a 3-D affine"):
        read_slicer_transform(path)


def test_an_h5_of_two_transforms_is_refused(tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    composite = sitk.CompositeTransform(
        [sitk.Euler3DTransform(), sitk.TranslationTransform(3, (1.0, 2.0, 3.0))]
    )
    path = tmp_path / "two.h5"
    sitk.WriteTransform(composite, str(path))
    with pytest.raises(InvalidInputError, match="holds 2 transforms"):
        read_slicer_transform(path)
