from lesscli.cli.main import entry

entry()
