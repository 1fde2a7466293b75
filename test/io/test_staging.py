"""io/staging.py: outputs appear whole or not at all, and a failure leaves nothing behind."""
import pytest

from map_consistency_ros.io.staging import StagedOutputs, staged


def _everything(folder):
    return sorted(str(path.relative_to(folder)) for path in folder.rglob('*'))


def test_an_output_appears_only_when_written_whole(tmp_path):
    final = tmp_path / 'out' / 'report.json'
    with staged(final) as target:
        assert target.name == 'report.json' and target.parent.parent == final.parent
        target.write_text('{}')
        assert not final.exists()  # not yet: a reader never sees it half-written
    assert final.read_text() == '{}'
    assert _everything(tmp_path) == ['out', 'out/report.json']


def test_a_failure_removes_the_output_and_the_folders_made_for_it(tmp_path):
    (tmp_path / 'kept').mkdir()
    final = tmp_path / 'kept' / 'new' / 'deeper' / 'map.png'
    with pytest.raises(RuntimeError):
        with staged(final) as target:
            target.write_bytes(b'half a')
            raise RuntimeError('the writer broke')
    assert _everything(tmp_path) == ['kept']


def test_an_existing_file_is_replaced_and_a_folder_refused(tmp_path):
    final = tmp_path / 'table.csv'
    final.write_text('old')
    with pytest.raises(RuntimeError):
        with staged(final) as target:
            target.write_text('new, half')
            raise RuntimeError
    assert final.read_text() == 'old'  # a failed rewrite keeps the old file
    with staged(final) as target:
        target.write_text('new')
    assert final.read_text() == 'new'
    with pytest.raises(IsADirectoryError):
        with staged(tmp_path) as target:
            target.write_text('x')
    assert _everything(tmp_path) == ['table.csv']


def test_several_outputs_appear_together_or_not_at_all(tmp_path):
    with pytest.raises(ValueError):
        with StagedOutputs() as outputs:
            outputs.path(tmp_path / 'a.json').write_text('{}')
            outputs.path(tmp_path / 'figures' / 'b.png').write_bytes(b'png')
            raise ValueError('the third output failed')
    assert _everything(tmp_path) == []
    with StagedOutputs() as outputs:
        outputs.path(tmp_path / 'a.json').write_text('{}')
        outputs.path(tmp_path / 'bag').mkdir()  # a folder output, as a bag writer makes
        (tmp_path / 'unused').mkdir()
        outputs.path(tmp_path / 'unused' / 'never_written.csv')
    assert _everything(tmp_path) == ['a.json', 'bag', 'unused']


def test_an_output_whose_folder_cannot_be_made_is_named(tmp_path):
    (tmp_path / 'afile').write_text('')
    with pytest.raises(NotADirectoryError) as caught:
        with staged(tmp_path / 'afile' / 'bag'):
            pass
    assert caught.value.filename == str(tmp_path / 'afile' / 'bag')


def test_a_writer_error_names_the_output_not_its_hidden_stage(tmp_path):
    final = tmp_path / 'out' / 'map.png'
    with pytest.raises(OSError) as caught:
        with staged(final) as target:
            raise OSError(28, 'No space left on device', str(target))
    assert caught.value.filename == str(final) and caught.value.errno == 28
    assert _everything(tmp_path) == []
    with pytest.raises(ValueError):  # other errors pass through as they are
        with staged(final):
            raise ValueError('not a file error')
