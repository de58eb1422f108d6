"""`station errors`: the table of error and fault codes."""

from station.errors import all_error_classes


def add_arguments(parser):
    pass


def run(args) -> int:
    print(f"{'code':>5}  {'area':<12} name")
    for cls in all_error_classes():
        print(f"{cls.code:>5}  {cls.area:<12} {cls.__name__}")
    return 0
