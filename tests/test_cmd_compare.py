"""`vnl compare`: dispatch through the registry of measures and its input checks (no heavy
imports, exit 2 with one line)."""

from vnl.cli import main


def test_compare_rejects_mistakes_with_one_line(capsys):
    cases = [
        (["compare", "a", "b", "--measure", "rdm", "--rdm-comparison", "nope"], "unknown RDM comparison"),
        (["compare", "a", "b", "--measure", "dsa", "--rsa", "euclidean"], "cannot be combined"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert message in err and err.count("\n") == 1, (argv, err)
