"""scripts/bench_rig_poses.py: the folder of rigged animals it trains on."""

from litege_core.synth.folder import list_meshes
from litege_core.synth.rigged import ANIMALS, animal_path


def test_the_rigs_are_linked_once_under_their_names(bench_rig_poses, tmp_path):
    data = tmp_path / "train-data"
    for animal in ANIMALS:
        source = animal_path(data, animal)
        source.parent.mkdir(parents=True, exist_ok=True)
        source.write_bytes(animal.encode())
    folder = tmp_path / "rigs"
    names = bench_rig_poses.link_rigs(folder, data)
    assert len(names) == len(ANIMALS) == 12 and "KhronosFox.glb" in names
    assert sorted(names) == list(list_meshes(folder))  # every link is a mesh file it trains on
    assert bench_rig_poses.link_rigs(folder, data) == names  # again: nothing to do
    assert (folder / "Wolf.gltf").read_bytes() == b"Wolf"
