from grt.cli.report import cli

if __name__ == "__main__":
    cli()
